"""Test configuration: float64 everywhere (precision matters in the reference checks),
``--runslow`` for the full-size end-to-end runs (CI runs their small versions), and one
persistent XLA compilation cache per pytest run, so tests that build the same controller
(walking, sweeps, experiments) compile it once. The cache lives in a fresh temporary
folder: every run compiles from scratch, nothing carries over between runs. Programs compile
at XLA:CPU's LLVM optimisation level 0 (see below). Under
``pytest -n 2 --dist loadfile`` (``make test``) the controller process makes the folder
and both workers inherit it through the environment, so a program one worker compiled is
a cache hit for the other (full suites have run this way, all passing)."""

import os
import tempfile

import jax
import pytest

from jaxloco.runtime import configure, enable_compilation_cache

# The suite compiles hundreds of programs and runs most of them for a few ticks, so it
# compiles at XLA:CPU's LLVM optimisation level 0: the same HLO, results equal to float
# round-off. Measured on 2 cores: the walking tick (plain jit) compiled in 3.1 s against
# 7.8 s and ran as fast; the one-core programs, whose matrix products are XLA's own kernels
# (runtime.single_thread_compiler_options), run slower at level 0 (the G1's batch-64 tick
# 3.5x, one call 1.5x), which the suite's short runs more than repay: the whole suite
# passed in 500 s against 620 s at the default level. Programs that set their own level
# (the RBF learning programs) keep it, and so does a level given in XLA_FLAGS. The CLI,
# the benchmarks and `make run` compile at XLA's default level.
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=0"
    ).strip()
configure()  # the XLA options the CLI and benchmarks use, before any test computes
jax.config.update("jax_enable_x64", True)
if "JAXLOCO_TEST_CACHE_DIR" not in os.environ:  # the xdist controller, or a plain run
    _CACHE = tempfile.TemporaryDirectory(prefix="jaxloco-test-xla-")  # removed at exit
    os.environ["JAXLOCO_TEST_CACHE_DIR"] = _CACHE.name  # xdist workers inherit it
os.environ["JAXLOCO_CACHE_DIR"] = os.environ["JAXLOCO_TEST_CACHE_DIR"]  # in-process CLIs too
enable_compilation_cache(os.environ["JAXLOCO_TEST_CACHE_DIR"])


@pytest.fixture(scope="session")
def installed_jaxloco(tmp_path_factory):
    """The project's wheel installed into a temporary folder (its ``sys.path`` entry): the
    package as a user's ``pip install .`` has it, away from the checkout."""
    from cli_helpers import install_wheel

    return install_wheel(tmp_path_factory.mktemp("wheel"))


def pytest_addoption(parser):
    parser.addoption("--runslow", action="store_true", help="also run tests marked slow")
    parser.addoption(
        "--compile-report",
        metavar="PATH",
        help="write each test's JAX trace, lowering and compile seconds to PATH (JSON lines)",
    )


# Files in the order the two workers should start them (``make test`` passes
# ``--no-loadscope-reorder`` so xdist keeps it): the longest first, so no long file starts
# last while the other worker idles. Measured on 2 cores (s of test time):
# locomotion 654, wblc 538, tuning 429, docs 326, sweep 242, robot_models 200, dynamics 167,
# training 112, the rest < 90. The order also decides which file compiles a shared program
# and which reads it from the run's cache: files ordered by their own times instead
# (docs, wblc, locomotion, tuning, dynamics, ...) balanced the workers (704 and 705 s busy)
# and took 725 s against 608, the files that had read the walking tick from the cache
# compiling it themselves (the main-job limit test 24 -> 53 s).
LONGEST_FIRST = (
    "test_locomotion",
    "test_wblc",
    "test_sweep",
    "test_tuning",
    "test_docs",
    "test_robot_models",
    "test_dynamics",
)


def _file_rank(item) -> int:
    stem = item.path.stem
    return LONGEST_FIRST.index(stem) if stem in LONGEST_FIRST else len(LONGEST_FIRST)


def pytest_collection_modifyitems(config, items):
    items.sort(key=_file_rank)  # stable: tests keep their order within a file
    if config.getoption("--runslow"):
        return
    skip = pytest.mark.skip(reason="full-size run: use --runslow (make test-all)")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)


# --- where the suite's time goes -------------------------------------------------------
# ``pytest --compile-report PATH``: per test, the seconds this process spent tracing,
# lowering and compiling JAX programs (JAX's own monitoring events; programs compiled in
# subprocesses, e.g. CLI runs and Dask workers, are not seen), written as JSON lines to
# PATH (one file per xdist worker: PATH.gw0, PATH.gw1).
_COMPILE_EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace_s",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s",
    "/jax/core/compile/backend_compile_duration": "compile_s",
}
_compile_seconds: dict[str, float] = {}


def _record_compile_event(event: str, duration: float, **_) -> None:
    key = _COMPILE_EVENTS.get(event)
    if key is not None:
        _compile_seconds[key] = _compile_seconds.get(key, 0.0) + duration
        if key == "compile_s":
            _compile_seconds["programs"] = _compile_seconds.get("programs", 0) + 1


def pytest_configure(config):
    if config.getoption("--compile-report", default=None):
        jax.monitoring.register_event_duration_secs_listener(_record_compile_event)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    path = item.config.getoption("--compile-report", default=None)
    if not path:
        yield
        return
    import json
    import time

    _compile_seconds.clear()
    start = time.perf_counter()
    yield
    row = {"test": item.nodeid, "wall_s": round(time.perf_counter() - start, 2)}
    row.update({k: round(v, 2) for k, v in _compile_seconds.items()})
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    with open(f"{path}.{worker}" if worker else path, "a") as f:
        f.write(json.dumps(row) + "\n")
