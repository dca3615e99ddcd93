"""Process-level set-up shared by the CLI, experiments and benchmarks.

Nothing here runs on import: callers opt in (the library itself holds no global state).
"""

from __future__ import annotations

import contextlib
import faulthandler
import importlib.util
import io
import json
import logging
import os
import sys
from pathlib import Path

import jax
import numpy as np

DEFAULT_CACHE_DIR = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "jaxloco"


def assets_dir() -> Path:
    """The folder of the models, shipped policies and gains: ``$JAXLOCO_ASSETS_DIR`` if set,
    else the installed package ``jaxloco.assets`` (the repository's ``assets/``, installed
    as package data), else ``assets/`` next to the package (a source tree not installed)."""
    env = os.environ.get("JAXLOCO_ASSETS_DIR")
    if env:
        return Path(env)
    try:
        spec = importlib.util.find_spec("jaxloco.assets")
    except ImportError:
        spec = None
    if spec is not None and spec.submodule_search_locations:
        return Path(next(iter(spec.submodule_search_locations)))
    return Path(__file__).resolve().parents[1] / "assets"


SMALL_LOOP_BYTES = 52_000
"""XLA:CPU compiles a while loop (``lax.scan``, ``fori_loop``) whose one iteration touches
fewer bytes than this into a single kernel, instead of dispatching each operation of each
iteration separately (XLA's own default: 1 kB). 52 kB takes in the force QP's ADMM loop of
one robot and the hierarchy's 3 x 3 Jacobi loops batched 64 (48-52 kB an iteration: about
40 kernels a sweep, dispatched), and leaves out the ADMM loop batched 16 (the C backend's
chunks; 52-56 kB an iteration) and 64 (taken in at 64 kB, it ran slower; docs/
architecture.md, measured choices)."""


def configure(small_loop_bytes: int = SMALL_LOOP_BYTES, fusion_emitters: bool = False) -> None:
    """Set jaxloco's XLA:CPU options for this process, through ``XLA_FLAGS``.

    Call it before JAX runs its first computation (the ``jaxloco`` command, the experiments,
    the benchmarks and the tests do); processes started afterwards inherit it. Options the
    user already set in ``XLA_FLAGS`` are kept as they are. It sets:

    - ``--xla_cpu_enable_concurrency_optimized_scheduler=false``: with it on, XLA:CPU has
      deadlocked (0% CPU, stuck in ``block_until_ready``) on vmapped programs with several
      independent LAPACK calls; turning it off fixed every such hang we reproduced.
    - ``xla_cpu_small_while_loop_byte_threshold`` (:data:`SMALL_LOOP_BYTES`).
    - ``--xla_cpu_use_fusion_emitters=false`` unless ``fusion_emitters``: XLA:CPU's
      MLIR-based fusion emitters build an MLIR module per fused kernel, and the controller's
      programs have about a thousand kernels; its LLVM IR emitters compile the walking
      controller in about two thirds of the time, and the programs they make run within a
      few percent as fast (docs/architecture.md, measured choices).

    Called after JAX's backends exist (after a first computation), it changes nothing
    that takes effect.
    """
    if small_loop_bytes < 0:
        raise ValueError(f"configure: small_loop_bytes must be >= 0; got {small_loop_bytes}")
    flags = os.environ.get("XLA_FLAGS", "")
    wanted = []
    if "xla_cpu_enable_concurrency_optimized_scheduler" not in flags:
        wanted.append("--xla_cpu_enable_concurrency_optimized_scheduler=false")
    if "xla_cpu_use_fusion_emitters" not in flags:
        wanted.append(f"--xla_cpu_use_fusion_emitters={str(fusion_emitters).lower()}")
    if "xla_backend_extra_options" not in flags:
        wanted.append(
            f"--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold={small_loop_bytes}"
        )
    if wanted:
        os.environ["XLA_FLAGS"] = " ".join([flags, *wanted]).strip()
    import_mjx_quietly()


def import_mjx_quietly() -> None:
    """Import MuJoCo's MJX without the "Failed to import warp" lines it prints when NVIDIA
    Warp (an optional GPU backend jaxloco does not use) is not installed. Other output and
    errors of the import pass through; :func:`configure` calls it."""
    if "mujoco.mjx" in sys.modules:
        return
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        import mujoco.mjx  # noqa: F401, PLC0415
    for line in buffer.getvalue().splitlines():
        if not line.startswith(("Failed to import warp", "Failed to import mujoco_warp")):
            print(line)


def dask_setup(worker) -> None:
    """Dask's preload hook (``LocalCluster(preload=["jaxloco.runtime"])``, ``dask worker
    --preload jaxloco.runtime``): a worker process imports MJX quietly (:func:`
    import_mjx_quietly`) before its first task brings code that imports it."""
    import_mjx_quietly()


def enable_compilation_cache(cache_dir: str | os.PathLike | None = None) -> Path:
    """Turn on JAX's persistent compilation cache so a second run skips XLA compiles.

    Directory: ``cache_dir``, else ``$JAXLOCO_CACHE_DIR``, else ``~/.cache/jaxloco/xla``.
    Every compile is stored, the small ones too: building a controller runs hundreds of
    one-operation programs outside ``jit`` (MJX's ``put_model``, set-up arithmetic), and a
    new process (a second run, each Dask worker) reads them back faster than it compiles
    them again.
    """
    path = Path(cache_dir or os.environ.get("JAXLOCO_CACHE_DIR", DEFAULT_CACHE_DIR / "xla"))
    path.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path


def cpu_compiler_options() -> dict | None:
    """``jax.jit(..., compiler_options=...)`` for the RBF learning programs on the CPU.

    XLA:CPU's LLVM optimisation level 1 instead of its default: the RBF window's gathers
    and scatters run faster with it, it compiles as fast, and the results agree up to float
    round-off (``docs/learning.md``). ``None`` (XLA's defaults) on other backends.
    """
    return {"xla_backend_optimization_level": 1} if jax.default_backend() == "cpu" else None


def single_thread_compiler_options() -> dict | None:
    """``jax.jit(..., compiler_options=...)`` for the controller's programs that run on one
    core: the closed loops' tick for one robot and the sweeps' batched tick (one worker per
    core). XLA:CPU calls Eigen's single-threaded kernels instead of handing matrix products
    to its intra-op thread pool (``docs/sweep.md``), and leaves matrix products to its own
    kernels instead of fusing them into YNNPACK calls: the controller's products are a few
    dozen rows each, and a library call per product (per robot of a batch) costs more than
    it saves, at one robot and at batches of 16 to 256 alike (docs/architecture.md,
    measured choices). ``None`` (XLA's defaults) on other backends. A compile option rather
    than an ``XLA_FLAGS`` setting: the driver that compiles the program into the persistent
    cache and the workers that load it must agree on its cache key, and every process must
    run the same program for outcomes to be bit-identical wherever a chunk runs."""
    if jax.default_backend() != "cpu":
        return None
    return {"xla_cpu_multi_thread_eigen": False, "xla_cpu_experimental_ynn_fusion_type": ""}


@contextlib.contextmanager
def watchdog(seconds: float, what: str = "this run"):
    """Fail loudly if the block takes longer than ``seconds``.

    XLA on CPU has been seen to hang inside ``block_until_ready``; rather than wait
    forever, dump every thread's stack to stderr and exit the process with status 1.
    """
    if seconds <= 0:
        raise ValueError(f"watchdog seconds must be > 0; got {seconds}")
    print(f"[watchdog] {what}: limit {seconds:.0f} s", file=sys.stderr, flush=True)
    faulthandler.dump_traceback_later(seconds, exit=True)
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()


def quiet_library_logs() -> None:
    """Hide INFO lines a user cannot act on: JAX's about accelerator plug-ins it did not
    find (e.g. no TPU) and MJX's "Using JAX default device" (logged on the root logger at
    every ``put_model``). Dask's are quieted where its client lives
    (:func:`jaxloco.sweep.cluster.dask_client`)."""
    logging.getLogger("jax._src.xla_bridge").setLevel(logging.WARNING)
    root = logging.getLogger()
    if not any(isinstance(f, _MjxDeviceLine) for f in root.filters):
        root.addFilter(_MjxDeviceLine())


class _MjxDeviceLine(logging.Filter):
    """Drops MJX's "Using JAX default device: ..." record."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith("Using JAX default device")


def to_jsonable(obj):
    """Convert arrays, numpy scalars and nested containers into JSON-serialisable values."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, (jax.Array, np.ndarray, np.generic)):
        return np.asarray(obj).tolist()
    return obj


def write_json(path: str | os.PathLike, obj) -> Path:
    """Write ``obj`` as indented JSON (arrays become lists); returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(to_jsonable(obj), indent=2) + "\n")
    return path
