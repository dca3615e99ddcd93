"""The package as installed: every subpackage listed in pyproject.toml, and a wheel that
carries the assets and the experiments, so a non-editable install loads the model and the
shipped policy and its ``jaxloco`` command lists and runs the experiments."""

import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

from cli_helpers import installed_env

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
