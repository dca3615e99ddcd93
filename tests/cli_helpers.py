"""Running the ``jaxloco`` CLI in a subprocess, for the CI-sized end-to-end tests: from the
checkout, or from the package as ``pip install`` puts it elsewhere (a wheel)."""

import os
import subprocess
import sys
from pathlib import Path

from jaxloco.learning.checkpoint import SHIPPED_POLICIES, assets_dir

ROOT = Path(__file__).resolve().parent.parent

CI_SEARCH = [
    "search.directions_deg=[0.0]",
    "search.phases=[0.5]",
    "search.replan=[true]",
    "search.impulse_range=[0,40]",
    "search.rounds=2",
    "search.replicas=2",
    "search.min_recovered=1",
    "search.push_step=1",
    "search.horizon=0.8",
    "search.steps_after=1",
    "workers=1",
    "chunk_size=2",
    # The search's machinery, tested on Algorithm 1's policy alone: the default's
    # look-ahead makes the compile longer, and the walking tests cover it.
    f"planner={assets_dir() / SHIPPED_POLICIES['algorithm1']}",
]
"""``jaxloco push-sweep``'s overrides for a CI-sized main job (one cell, two rounds)."""
CI_PORTRAIT = [
    "portrait_steps=4",
    "steering_steps=[3,2]",
    "steering_degrees=[18.8,-10]",
    "lookahead.grid_shape=[5,5,5]",
    "dpi=60",
]
"""``jaxloco phase-portrait``'s overrides for a CI-sized run."""


def install_wheel(tmp_dir: Path) -> Path:
    """Build the project's wheel and install it (no dependencies: they are this venv's)
    into ``tmp_dir/site``; returns that folder, the installed package's ``sys.path``
    entry."""
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", str(tmp_dir), "."],
        cwd=ROOT,
        check=True,
        timeout=600,
    )
    (wheel,) = tmp_dir.glob("jaxloco-*.whl")
    target = tmp_dir / "site"
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--target",
         str(target), str(wheel)],
        check=True,
        timeout=600,
    )  # fmt: skip
    return target


def installed_env(site: Path) -> dict:
    """The environment of a process that sees the package installed at ``site`` only: no
    checkout folders named by the environment."""
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("JAXLOCO_ASSETS_DIR", "JAXLOCO_EXPERIMENTS_DIR")
    }
    env["PYTHONPATH"] = str(site)
    return env


def run_cli(args, tmp_path, timeout=600, installed: Path | None = None):
    """``jaxloco ARGS hydra.run.dir=TMP/run`` from ``tmp_path``, sharing the pytest run's
    compile cache (``JAXLOCO_CACHE_DIR``, set by ``conftest.py``); ``installed``: run the
    package installed there (:func:`install_wheel`) instead of the checkout."""
    env = dict(os.environ) if installed is None else installed_env(installed)
    return subprocess.run(
        [sys.executable, "-m", "jaxloco.cli", *args, f"hydra.run.dir={tmp_path / 'run'}"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
