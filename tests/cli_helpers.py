"""Running the ``jaxloco`` CLI in a subprocess, for the CI-sized end-to-end tests."""

import os
import subprocess
import sys


def run_cli(args, tmp_path, timeout=600):
    """``python -m jaxloco.cli ARGS hydra.run.dir=TMP/run``, sharing the pytest run's
    compile cache (``JAXLOCO_CACHE_DIR``, set by ``conftest.py``)."""
    env = dict(os.environ)
    return subprocess.run(
        [sys.executable, "-m", "jaxloco.cli", *args, f"hydra.run.dir={tmp_path / 'run'}"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
