"""Process set-up: importing jaxloco changes nothing; ``configure()`` sets its XLA options
before the first computation and keeps the user's own."""

import json
import os
import subprocess
import sys

import pytest

from jaxloco.runtime import configure

PROBE = """
import json, os
before = os.environ.get("XLA_FLAGS")
import jaxloco, jaxloco.control, jaxloco.locomotion, jaxloco.sweep, jaxloco.tuning
from jax._src import xla_bridge
imported = {"flags": os.environ.get("XLA_FLAGS"), "backends": xla_bridge.backends_are_initialized()}
from jaxloco.runtime import configure
configure()
print(json.dumps({"before": before, "imported": imported, "after": os.environ.get("XLA_FLAGS")}))
"""


def probe(xla_flags):
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    if xla_flags is not None:
        env["XLA_FLAGS"] = xla_flags
    out = subprocess.run(
        [sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_import_changes_nothing_and_configure_sets_the_flags():
    seen = probe(None)
    # Importing the packages neither sets flags nor starts JAX's backends (after which
    # flags would be ignored).
    assert seen["imported"] == {"flags": None, "backends": False}
    assert "--xla_cpu_enable_concurrency_optimized_scheduler=false" in seen["after"]
    assert "xla_cpu_small_while_loop_byte_threshold=52000" in seen["after"]
    assert "--xla_cpu_use_fusion_emitters=false" in seen["after"]


def test_configure_keeps_the_users_flags():
    mine = "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=0"
    seen = probe(mine)
    assert seen["after"].split().count(mine) == 1
    assert seen["after"].count("xla_backend_extra_options") == 1
    assert "concurrency_optimized_scheduler=false" in seen["after"]


def test_configure_keeps_the_users_choice_of_emitters():
    seen = probe("--xla_cpu_use_fusion_emitters=true")
    assert seen["after"].count("xla_cpu_use_fusion_emitters") == 1
    assert "--xla_cpu_use_fusion_emitters=true" in seen["after"]


def test_configure_rejects_a_negative_threshold():
    with pytest.raises(ValueError, match="small_loop_bytes"):
        configure(small_loop_bytes=-1)


def test_configure_imports_mjx_without_the_warp_line():
    """MJX prints "Failed to import warp" without NVIDIA Warp (an optional GPU backend);
    after ``configure()`` a command's output does not carry it."""

    def output(code):
        out = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, timeout=300
        )
        assert out.returncode == 0, out.stderr
        return out.stdout

    if "warp" not in output("from mujoco import mjx"):
        pytest.skip("this environment's MJX prints nothing on import (Warp installed?)")
    configured = "from jaxloco.runtime import configure\nconfigure()\nfrom mujoco import mjx"
    assert output(configured + "\nprint('ok')").strip() == "ok"


@pytest.mark.parametrize(
    "code",
    [
        "import jaxloco.control.tasks",  # brax's math imports MJX
        "import jaxloco.dynamics.se3",
        "import jaxloco.sim",
        # A Dask worker of a `jaxloco push-sweep` re-imports its parent's main module, the
        # experiment script, before its preload runs.
        "import runpy; runpy.run_path('experiments/push_sweep.py', run_name='__mp_main__')",
    ],
)
def test_the_library_imports_mjx_without_the_warp_line(code):
    """Whichever library module a process imports first, MJX's import stays quiet."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out = subprocess.run(
        [sys.executable, "-c", "from mujoco import mjx"], capture_output=True, text=True,
        timeout=300,
    )  # fmt: skip
    if "warp" not in out.stdout:
        pytest.skip("this environment's MJX prints nothing on import (Warp installed?)")
    out = subprocess.run(
        [sys.executable, "-c", code + "\nprint('ok')"], capture_output=True, text=True,
        timeout=300, cwd=root,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "ok"


def test_single_threaded_programs_leave_matrix_products_to_xla():
    """The controller's one-core programs (one robot or a batch) run Eigen's single-threaded
    kernels and compile matrix products as XLA's own kernels, not YNNPACK fusions, and the
    options are ones XLA accepts (the program runs)."""
    import jax
    import jax.numpy as jnp

    from jaxloco.runtime import single_thread_compiler_options

    options = single_thread_compiler_options()
    assert options == {
        "xla_cpu_multi_thread_eigen": False,
        "xla_cpu_experimental_ynn_fusion_type": "",
    }
    # A batch of the controller's sizes and dtype, which XLA's defaults hand to YNNPACK.
    x = jnp.linspace(0.0, 1.0, 8 * 35 * 35, dtype=jnp.float32).reshape(8, 35, 35)
    f = jax.jit(jax.vmap(lambda a: a @ a.T), compiler_options=options)
    assert "ynn" not in f.lower(x).compile().as_text()
    assert "ynn" in jax.jit(jax.vmap(lambda a: a @ a.T)).lower(x).compile().as_text()
    assert jnp.allclose(f(x), x @ jnp.swapaxes(x, 1, 2), rtol=1e-5)
