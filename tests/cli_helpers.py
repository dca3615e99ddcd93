"""Running the ``jaxloco`` CLI in a subprocess, for the CI-sized end-to-end tests: from the
checkout, or from the package as ``pip install`` puts it elsewhere (a wheel)."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


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
