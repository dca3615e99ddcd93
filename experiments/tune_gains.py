"""Tune WBLC gains by gradient through a differentiable MJX rollout (body shaking, Fig. 10).

    jaxloco tune-gains                                   # body and pelvis gains of H1
    jaxloco tune-gains problem.hierarchy=H2
    jaxloco tune-gains 'tuned=[body_ori.kp,body_ori.kd,com.kp]' tune.iterations=50
    jaxloco tune-gains tune.method=lbfgs tune.gradient=reverse
    jaxloco tune-gains 'pushes=[[150,90],[150,-90]]'    # also robust to pelvis pushes

Tuning: Valkyrie stands in double support in MJX (one solver iteration, so gradients
flow) while its body follows the shaking reference; the loss is the body-orientation
error plus effort (and the CoM drift and falls of any training pushes, and with
``problem.slip_weight`` the creep of the feet), see :mod:`jaxloco.tuning.problems`. Optax
minimises it over log-scales of the named gains.

Held-out measure: the hand-set and the tuned gains each run the body-shaking experiment
on MuJoCo's C engine with its default solver, for ``heldout_duration`` s at every
frequency in ``heldout_frequencies`` (tuning sees only ``shaking.frequency_hz``, or
``problem.frequencies``, over ``problem.horizon``), and reports how far the feet crept
(``final_foot_slip_m``). Writes ``tuned_gains.json`` (load it anywhere with
``gains_file=...``), ``history.json``, ``loss_curve.png``, ``before_after.png`` (body
error, torque and foot creep) and ``summary.json`` to the run directory.
"""

import dataclasses
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import hydra
import jax.numpy as jnp
import numpy as np
from hydra.core.config_store import ConfigStore
from hydra.core.hydra_config import HydraConfig
from matplotlib.figure import Figure
from omegaconf import OmegaConf

from jaxloco.config import config_schema, to_params
from jaxloco.control.gains import save_gains, with_gains
from jaxloco.control.presets import body_shaking_config
from jaxloco.control.shaking import ShakingParams
from jaxloco.dynamics.model import load_valkyrie
from jaxloco.runtime import enable_compilation_cache, quiet_jax_logs, watchdog, write_json
from jaxloco.sim.shaking import shaking_metrics, simulate_shaking
from jaxloco.tuning.gains import GainSpace, tuned_values
from jaxloco.tuning.optimize import TuneConfig, tune_in_dir
from jaxloco.tuning.problems import ShakingLossParams, shaking_loss
from jaxloco.tuning.rollout import tuning_physics
from jaxloco.viz.tuning import plot_loss_curve

log = logging.getLogger(__name__)

ProblemSchema = config_schema(ShakingLossParams)
ShakingSchema = config_schema(ShakingParams)
TuneSchema = config_schema(TuneConfig)


@dataclass
class TuneGainsConfig:
    tuned: list[str] = field(
        default_factory=lambda: ["body_ori.kp", "body_ori.kd", "pelvis_ori.kp", "pelvis_ori.kd"]
    )
    """Gains to tune, ``task.kp`` or ``task.kd`` (tasks of the body-shaking config)."""
    per_row: bool = False
    max_log_scale: float = 3.0
    problem: ProblemSchema = field(default_factory=ProblemSchema)
    shaking: ShakingSchema = field(default_factory=ShakingSchema)
    tune: TuneSchema = field(default_factory=TuneSchema)
    # list[Any]: OmegaConf rejects ints (`[[520,0]]`) in a typed nested list.
    pushes: list[Any] = field(default_factory=lambda: [[0.0, 0.0]])
    """Training pushes on the pelvis, ``[force N, direction deg]``, one rollout each
    (averaged); ``[0, 0]``: no push."""
    push_start: float = 0.3
    push_duration: float = 0.1
    heldout_duration: float = 5.0
    heldout_frequencies: list[float] = field(default_factory=lambda: [1.0, 1.5])
    timeout_s: float = 3600.0
    dpi: int = 120


ConfigStore.instance().store(name="tune_gains", node=TuneGainsConfig)

LOSS_TERMS = ("track", "effort", "com", "slip", "fallen")


def training_pushes(cfg) -> jnp.ndarray:
    rows = []
    for k, p in enumerate(cfg.pushes):
        if len(p) != 2 or p[0] < 0:
            raise ValueError(f"pushes[{k}]: want [force N >= 0, direction deg]; got {list(p)}")
        rows.append([p[0], np.deg2rad(p[1]), cfg.push_start, cfg.push_duration])
    return jnp.asarray(rows, dtype=jnp.float32)


def heldout(model, config, shaking: ShakingParams, cfg) -> dict:
    out = {}
    for f in cfg.heldout_frequencies:
        params = dataclasses.replace(shaking, frequency_hz=float(f))
        res = simulate_shaking(model, config, params, cfg.heldout_duration)
        out[f"{f:g}"] = {"metrics": shaking_metrics(res), "time": res.time, "log": res.outputs}
    return out


def plot_before_after(before, after, path: Path, dpi: int):
    freqs = list(before)
    fig = Figure(figsize=(14, 3.2 * len(freqs)), constrained_layout=True)
    axes = np.atleast_2d(fig.subplots(len(freqs), 3, squeeze=False))
    for row, f in enumerate(freqs):
        for name, runs, color in (("hand-set", before, "tab:gray"), ("tuned", after, "tab:blue")):
            r = runs[f]
            m = r["metrics"]
            axes[row, 0].plot(
                r["time"],
                r["log"]["body_error"],
                lw=1,
                color=color,
                label=f"{name} (RMS {m['rms_body_error_rad']:.4f} rad)",
            )
            axes[row, 1].plot(
                r["time"],
                r["log"]["torque_norm"],
                lw=1,
                color=color,
                label=f"{name} (mean {m['mean_torque_norm_Nm']:.0f} N m)",
            )
            axes[row, 2].plot(
                r["time"],
                100 * r["log"]["foot_slip"],
                lw=1,
                color=color,
                label=f"{name} (final {100 * m['final_foot_slip_m']:.1f} cm)",
            )
        axes[row, 0].set(ylabel="body error (rad)", title=f"held out: shaking at {f} Hz")
        axes[row, 1].set(ylabel="|tau| (N m)", title="torque norm")
        axes[row, 2].set(ylabel="foot slip (cm)", title="largest contact-point creep")
        for ax in axes[row]:
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    fig.suptitle("Body shaking on MuJoCo C (default solver): hand-set vs tuned gains")
    fig.savefig(path, dpi=dpi)


def run(cfg, out_dir: Path) -> dict:
    space = GainSpace(tuple(cfg.tuned), cfg.per_row, cfg.max_log_scale)
    problem = to_params(ShakingLossParams, cfg.problem)
    shaking = to_params(ShakingParams, cfg.shaking)
    tune_cfg = to_params(TuneConfig, cfg.tune)
    if cfg.heldout_duration <= 0 or not cfg.heldout_frequencies:
        raise ValueError("heldout_duration must be > 0 s and heldout_frequencies non-empty")
    pushes = training_pushes(cfg)
    model = load_valkyrie()
    loss, p0, base = shaking_loss(tuning_physics(model), space, problem, shaking)

    result = tune_in_dir(lambda p: loss(p, pushes), p0, tune_cfg, out_dir)
    values = tuned_values(space, result.params, base)
    config = body_shaking_config(problem.hierarchy, pinv_rtol=problem.pinv_rtol)
    hand = tuned_values(space, space.init(base), base)
    save_gains(
        out_dir / "tuned_gains.json",
        values,
        {
            "hierarchy": problem.hierarchy,
            "hand_set": hand,
            "best_loss": result.best_loss,
            "initial_loss": result.history[0]["loss"],
        },
    )
    fig = plot_loss_curve(result.history, LOSS_TERMS, "tuning loss")
    fig.savefig(out_dir / "loss_curve.png", dpi=cfg.dpi)

    before = heldout(model, config, shaking, cfg)
    after = heldout(model, with_gains(config, values), shaking, cfg)
    plot_before_after(before, after, out_dir / "before_after.png", cfg.dpi)
    summary = {
        "config": OmegaConf.to_container(OmegaConf.structured(cfg)),
        **result.summary(),
        "hand_set_gains": hand,
        "tuned_gains": values,
        "heldout": {
            f: {"hand_set": before[f]["metrics"], "tuned": after[f]["metrics"]} for f in before
        },
    }
    summary["heldout_improved"] = all(
        v["tuned"]["rms_body_error_rad"] < v["hand_set"]["rms_body_error_rad"]
        and not v["tuned"]["fell"]
        for v in summary["heldout"].values()
    )
    write_json(out_dir / "summary.json", summary)
    return {**summary, "tuning": result.describe()}


@hydra.main(version_base="1.3", config_path=None, config_name="tune_gains")
def main(cfg) -> None:
    quiet_jax_logs()
    enable_compilation_cache()
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    with watchdog(cfg.timeout_s, "tune-gains"):
        summary = run(cfg, out_dir)
    print(summary["tuning"])
    for f, v in summary["heldout"].items():
        h, t = v["hand_set"], v["tuned"]
        print(
            f"held out {f} Hz: RMS body error {h['rms_body_error_rad']:.4f} -> "
            f"{t['rms_body_error_rad']:.4f} rad, mean |tau| {h['mean_torque_norm_Nm']:.0f} -> "
            f"{t['mean_torque_norm_Nm']:.0f} N m, final foot slip "
            f"{100 * h['final_foot_slip_m']:.1f} -> {100 * t['final_foot_slip_m']:.1f} cm"
            + (" (tuned FELL)" if t["fell"] else "")
        )
    print(f"tuned gains: {out_dir / 'tuned_gains.json'} (use gains_file=... elsewhere)")


if __name__ == "__main__":
    main()
