"""The package as installed: every subpackage listed in pyproject.toml, and a wheel that
carries the assets and the experiments, so a non-editable install loads the model and the
shipped policy and its ``jaxloco`` command lists and runs the experiments."""

import json
import os
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest
from cli_helpers import CI_PORTRAIT, CI_SEARCH, installed_env

ROOT = Path(__file__).resolve().parent.parent


def test_every_subpackage_is_listed():
    listed = set(
        tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    found = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for p in (ROOT / "jaxloco").rglob("__init__.py")
        if "__pycache__" not in p.parts
    }
    assert found | {"jaxloco.assets", "jaxloco.experiments"} == listed


def test_a_wheel_install_loads_the_packaged_assets(installed_jaxloco, tmp_path):
    """The wheel carries the assets and the experiments; installed away from the checkout,
    it loads the model and the shipped policy, and its command lists the experiments and
    composes their configs (the CI-sized phase portrait and main job run it for real:
    ``test_experiments.py``, ``test_limits.py``)."""
    (wheel,) = installed_jaxloco.parent.glob("jaxloco-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for asset in (
        "jaxloco/assets/valkyrie/valkyrie.xml",
        "jaxloco/assets/planar3dof.xml",
        "jaxloco/assets/policies/rl_psp/weights.npz",
        "jaxloco/assets/policies/rl_psp_refined/config.json",
        "jaxloco/assets/policies/rl_psp_fallback/fallback.json",
        "jaxloco/assets/gains/body_shaking_h1_bandwidth.json",
        "jaxloco/experiments/push_sweep.py",
        "jaxloco/experiments/walk_steer.py",
    ):
        assert asset in names
    code = (
        "from jaxloco.runtime import assets_dir\n"
        "from jaxloco.dynamics.model import load_valkyrie\n"
        "from jaxloco.learning import load_planner\n"
        "print('RESULT', assets_dir(), load_valkyrie().nv, type(load_planner()).__name__)\n"
    )
    env = installed_env(installed_jaxloco)

    def installed(*args):
        out = subprocess.run(
            [sys.executable, "-c", *args],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert out.returncode == 0, out.stderr[-2000:]
        return out.stdout

    out = installed(code)
    (line,) = [x for x in out.splitlines() if x.startswith("RESULT ")]
    _, assets, nv, planner = line.split()
    assert Path(assets).resolve() == (installed_jaxloco / "jaxloco" / "assets").resolve()
    assert nv == "34"
    assert planner == "FallbackPlanner"  # its two policies found beside it in the wheel

    # The command as a user runs it: the listing, then an experiment's config from hydra.
    cli = "import sys; from jaxloco.cli import main; main(sys.argv[1:])"
    listing = installed(cli)
    assert "push-sweep" in listing and "walk-steer" in listing
    assert "planner:" in installed(cli, "phase-portrait", "--cfg", "job")


@pytest.mark.slow
def test_a_clean_venv_install_runs_the_commands_from_any_folder(installed_jaxloco, tmp_path):
    """The wheel as a user installs it: ``pip install`` into a new virtual environment
    (its dependencies resolved there, from the project's constraints), then the
    ``jaxloco`` command it puts on the venv's path, run from a folder outside the checkout
    with no ``PYTHONPATH``: the listing, a CI-sized phase portrait and a CI-sized main job
    with its report."""
    (wheel,) = installed_jaxloco.parent.glob("jaxloco-*.whl")
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    pip = subprocess.run(
        [venv / "bin" / "python", "-m", "pip", "install", "--quiet", "-c",
         ROOT / "constraints.txt", wheel],
        capture_output=True, text=True, timeout=1200,
    )  # fmt: skip
    assert pip.returncode == 0, pip.stderr[-3000:]  # pip's own reason, not only its exit code
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("PYTHONPATH", "JAXLOCO_ASSETS_DIR", "JAXLOCO_EXPERIMENTS_DIR", "VIRTUAL_ENV")
    }

    def jaxloco(*args):
        out = subprocess.run(
            [venv / "bin" / "jaxloco", *args],
            cwd=elsewhere, env=env, capture_output=True, text=True, timeout=900,
        )  # fmt: skip
        assert out.returncode == 0, out.stderr[-3000:]
        return out

    assert "push-sweep" in jaxloco().stdout
    jaxloco("phase-portrait", *CI_PORTRAIT, "hydra.run.dir=portrait")
    assert (elsewhere / "portrait" / "phase_portrait.png").stat().st_size > 0
    jaxloco("push-sweep", *CI_SEARCH, "hydra.run.dir=limits")
    summary = json.loads((elsewhere / "limits" / "summary.json").read_text())
    assert summary["cells"][0]["tested_Ns"] == [20.0, 30.0]
    assert (elsewhere / "limits" / "limits_polar.png").stat().st_size > 0
