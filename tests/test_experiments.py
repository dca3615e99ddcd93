"""The hydra config bridge, the ``jaxloco`` CLI, and CI-sized runs of the experiments."""

import dataclasses
import json
import sys
from pathlib import Path

import pytest
from cli_helpers import CI_PORTRAIT, run_cli
from omegaconf import OmegaConf

from jaxloco import cli
from jaxloco.config import config_schema, to_params
from jaxloco.planner import PSPParams

REPO = Path(__file__).resolve().parent.parent
JAXLOCO = [sys.executable, "-m", "jaxloco.cli"]


def test_config_schema_mirrors_params_and_accepts_overrides():
    schema = config_schema(PSPParams)
    cfg = OmegaConf.structured(schema)
    assert {f.name for f in dataclasses.fields(schema)} == {
        f.name for f in dataclasses.fields(PSPParams)
    }
    assert to_params(PSPParams, cfg) == PSPParams()
    cfg.h = 0.95  # mutable, unlike the frozen params node
    assert to_params(PSPParams, cfg).h == 0.95
    cfg.h = -1.0
    with pytest.raises(ValueError, match=r"PSPParams\.h must be > 0"):
        to_params(PSPParams, cfg)
    with pytest.raises(ValueError, match=r"no field\(s\) \['hh'\]"):
        to_params(PSPParams, {"hh": 1.0})


def test_cli_lists_experiments(capsys):
    cli.main([])
    out = capsys.readouterr().out
    assert "phase-portrait" in out


def test_cli_rejects_unknown_experiment():
    with pytest.raises(SystemExit, match="unknown experiment 'nope'"):
        cli.main(["nope"])


def test_phase_portrait_ci_sized(tmp_path, installed_jaxloco):
    """From the installed wheel, away from the checkout, as a user runs it."""
    proc = run_cli(
        ["phase-portrait", *CI_PORTRAIT],
        tmp_path,
        installed=installed_jaxloco,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    run = tmp_path / "run"
    for name in ("phase_portrait.png", "steering_walk.png", "plans.json"):
        assert (run / name).stat().st_size > 0, name
    plans = json.loads((run / "plans.json").read_text())
    assert plans["config"]["lookahead"]["grid_shape"] == [5, 5, 5]
    assert len(plans["steering_walk"]["footsteps"]) == 6
    assert plans["steering_walk"]["headings_deg"][-1] == pytest.approx(18.8 * 3 - 10 * 2)
    # The nominal start walks on the nominal gait with any sensible policy.
    assert plans["portraits"][0]["safe_steps"] == 4


def test_phase_portrait_bad_override_names_the_field(tmp_path):
    proc = run_cli(["phase-portrait", "planner.h=-1"], tmp_path)
    assert proc.returncode != 0
    assert "PSPParams.h must be > 0" in proc.stderr


@pytest.mark.slow
def test_phase_portrait_full_defaults(tmp_path):
    proc = run_cli(["phase-portrait"], tmp_path, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    plans = json.loads((tmp_path / "run" / "plans.json").read_text())
    assert plans["steering_walk"]["safe_steps"] == 29


def test_push_sweep_config_carries_the_walking_force_qp():
    """``jaxloco push-sweep force_qp.FIELD=...`` reaches the walking WBLC; its defaults are
    the walking preset's (so existing run directories keep resuming)."""
    import importlib.util

    from jaxloco.cli import experiments_dir
    from jaxloco.control.force_qp import ForceQPParams
    from jaxloco.control.presets import CLOSED_LOOP_QP

    spec = importlib.util.spec_from_file_location("push_sweep", experiments_dir() / "push_sweep.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    cfg = OmegaConf.structured(module.PushSweepConfig)
    assert to_params(ForceQPParams, cfg.force_qp) == CLOSED_LOOP_QP
    cfg.force_qp.iterations = 300
    cfg.force_qp.rho = 0.1
    qp = to_params(ForceQPParams, cfg.force_qp)
    assert qp.iterations == 300 and qp.rho == 0.1
    cfg.force_qp.alpha = 2.5
    with pytest.raises(ValueError, match="alpha"):
        to_params(ForceQPParams, cfg.force_qp)


def test_sweep_report_names_a_missing_run_directory(tmp_path):
    """``jaxloco sweep-report`` is a hydra app: without ``run_dir``, or with one that holds
    no sweep, it stops with an error that says so."""
    from cli_helpers import run_cli

    missing = run_cli(["sweep-report"], tmp_path, timeout=300)
    assert missing.returncode != 0 and "run_dir: give a push-sweep run directory" in (
        missing.stderr
    ), missing.stderr[-2000:]
    empty = run_cli(["sweep-report", f"run_dir={tmp_path / 'nothing'}"], tmp_path, timeout=300)
    assert empty.returncode != 0
