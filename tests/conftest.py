"""Test configuration: float64 everywhere (precision matters in the reference checks),
``--runslow`` for the full-size end-to-end runs (CI runs their small versions), and one
persistent XLA compilation cache per test process, so tests that build the same controller
(walking, sweeps, experiments) compile it once. The cache lives in a fresh temporary
folder: every session compiles from scratch, nothing carries over between runs. Under
``pytest -n 2 --dist loadfile`` (``make test``) each worker has its own cache and runs
whole files, so the tests of one file still share their compiles."""

import os
import tempfile

import jax
import pytest

from jaxloco.runtime import enable_compilation_cache

jax.config.update("jax_enable_x64", True)
_CACHE = tempfile.TemporaryDirectory(prefix="jaxloco-test-xla-")
os.environ["JAXLOCO_CACHE_DIR"] = _CACHE.name  # experiments run in-process use it too
enable_compilation_cache(_CACHE.name)


def pytest_addoption(parser):
    parser.addoption("--runslow", action="store_true", help="also run tests marked slow")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--runslow"):
        return
    skip = pytest.mark.skip(reason="full-size run: use --runslow (make test-all)")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
