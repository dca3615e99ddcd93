"""Evaluate a trained RL-PSP planner: survival basin against baselines, Fig. 6, value map.

    jaxloco policy-eval                          # the Algorithm 1 policy shipped in assets/
    jaxloco policy-eval checkpoint=outputs/.../checkpoint num_states=8192

Writes to hydra's run directory: ``basins.json`` and ``basins.md`` (survival basin of the
fixed nominal action, the look-ahead search, the untrained and the trained policy),
``fig6_pushed_steps.png`` (phase plots of sequential steps from pushed states, untrained
vs trained) and ``value_map.png`` (learned value over the state box, basin boundary drawn).
"""

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import hydra
import jax
import jax.numpy as jnp
import numpy as np

from jaxloco.app import RunConfig, launch, register, run_in_hydra
from jaxloco.learning import LearnedPlanner, init_train_state, load_planner, steps_survived
from jaxloco.learning.checkpoint import SHIPPED_POLICIES, assets_dir, load_checkpoint_config
from jaxloco.learning.starts import uniform_states
from jaxloco.planner import make_lookahead_policy, plan_steps, sample_com_trajectory
from jaxloco.runtime import write_json
from jaxloco.tuning.step_planner import GradientPlannerParams, make_gradient_policy
from jaxloco.viz import plot_phase_portraits
from jaxloco.viz.learning import plot_value_map

log = logging.getLogger(__name__)


@dataclass
class PolicyEvalConfig(RunConfig):
    checkpoint: str = ""
    """An RL-PSP checkpoint folder; empty: the Algorithm 1 policy shipped in assets/ (the
    walking controller's default is it with a fallback, which has no value map to draw)."""
    num_states: int = 4096
    num_steps: int = 50
    seed: int = 2024
    fixed_action: list[float] = field(default_factory=lambda: [0.25, 0.2, 0.0])
    pushed_states: list[Any] = field(
        default_factory=lambda: [[0.05, 0.39, 0.33], [0.06, 0.45, -0.2], [0.04, 0.55, 0.0]]
    )
    """Post-impulse apex states for Fig. 6 (the first is the paper's)."""
    fig6_steps: int = 10
    gradient_planner_horizons: list[int] = field(default_factory=lambda: [1, 2])
    """Also evaluate the gradient-based step planner (jaxloco.tuning.step_planner) with
    these look-ahead horizons ([]: skip it)."""
    gradient_planner_iterations: int = 40
    timing_repeats: int = 50
    """Single-state decision time: median of this many jitted calls per policy."""
    value_map_resolution: int = 60
    value_map_yd: list[float] = field(default_factory=lambda: [0.0])
    dpi: int = 130


register("policy_eval", PolicyEvalConfig)


def run(cfg: PolicyEvalConfig, out_dir: Path) -> dict:
    path = Path(cfg.checkpoint) if cfg.checkpoint else assets_dir() / SHIPPED_POLICIES["algorithm1"]
    trained = load_planner(path)
    if not isinstance(trained, LearnedPlanner):
        raise ValueError(
            f"checkpoint: {path} holds a {type(trained).__name__}; policy-eval reads RL-PSP "
            "checkpoints (its value maps are of the RBF network)"
        )
    config, info = load_checkpoint_config(path)
    untrained = LearnedPlanner(
        init_train_state(config.actor_critic, config.grid).params, config.grid, config.planner
    )
    psp = trained.psp
    states = uniform_states(jax.random.key(cfg.seed), cfg.num_states, config.starts)
    fixed = jnp.asarray(cfg.fixed_action)
    policies = {
        f"fixed action {tuple(cfg.fixed_action)}": lambda s: fixed.astype(s.dtype),
        "look-ahead search (1 step, 9x9x11 grid)": make_lookahead_policy(psp),
        "RL-PSP untrained": untrained.policy,
        "RL-PSP trained": trained.policy,
    }
    for h in cfg.gradient_planner_horizons:
        gp = GradientPlannerParams(horizon=int(h), iterations=cfg.gradient_planner_iterations)
        name = f"gradient planner ({h}-step, Adam {gp.iterations} it. x {gp.num_starts} starts)"
        policies[name] = make_gradient_policy(psp, gp)
    basins, decision_us = {}, {}
    for name, policy in policies.items():
        steps = jax.jit(lambda s, p=policy: steps_survived(p, s, psp, cfg.num_steps))(states)
        basins[name] = float(jnp.mean(steps == cfg.num_steps))
        decision_us[name] = 1e6 * _decision_seconds(policy, states[0], cfg.timing_repeats)
        log.info("survival basin %-40s %.3f", name, basins[name])

    # Fig. 6: sequential steps from pushed states, untrained vs trained.
    pushed = jnp.asarray(cfg.pushed_states, dtype=float)
    trajs, labels = [], []
    for name, planner in (("untrained", untrained), ("trained", trained)):
        for s in pushed:
            plan = plan_steps(s, planner.policy, psp, num_steps=cfg.fig6_steps)
            trajs.append(sample_com_trajectory(plan, psp))
            n = int(plan.num_safe_steps)
            labels.append(f"{name}, from ({s[0]:.2f}, {s[1]:.2f}, {s[2]:.2f}): {n} safe steps")
    fig = plot_phase_portraits(trajs, labels, title="Sequential steps from pushed states")
    fig.savefig(out_dir / "fig6_pushed_steps.png", dpi=cfg.dpi)

    # Value map with the basin boundary on (y, xd) slices of the box.
    low, high = config.starts.box_low, config.starts.box_high
    n = cfg.value_map_resolution
    y_axis, xd_axis = np.linspace(low[0], high[0], n), np.linspace(low[1], high[1], n)
    yy, xx = np.meshgrid(y_axis, xd_axis)
    for yd in cfg.value_map_yd:
        grid_states = jnp.asarray(np.stack([yy, xx, np.full_like(yy, yd)], -1).reshape(-1, 3))
        value = np.asarray(trained.value(grid_states)).reshape(n, n)
        steps = jax.jit(lambda s: steps_survived(trained.policy, s, psp, cfg.num_steps))(
            grid_states
        )
        survived = np.asarray(steps == cfg.num_steps).reshape(n, n)
        fig = plot_value_map(y_axis, xd_axis, value, survived, yd)
        suffix = "" if len(cfg.value_map_yd) == 1 else f"_yd{yd:+.2f}"
        fig.savefig(out_dir / f"value_map{suffix}.png", dpi=cfg.dpi)

    summary = {
        "checkpoint": str(path),
        "training_info": info,
        "survival_basin": basins,
        "decision_time_us": decision_us,
        "num_states": cfg.num_states,
        "num_steps": cfg.num_steps,
    }
    write_json(out_dir / "basins.json", summary)
    lines = ["| policy | survival basin | one decision (us, jitted, 1 state) |", "|---|---|---|"]
    lines += [f"| {k} | {v:.3f} | {decision_us[k]:.0f} |" for k, v in basins.items()]
    (out_dir / "basins.md").write_text(
        f"Survival basin: fraction of {cfg.num_states} uniform apex states (Eq. 1 box) from "
        f"which the policy walks {cfg.num_steps} steps.\n\n" + "\n".join(lines) + "\n"
    )
    return summary


def _decision_seconds(policy, state, repeats: int) -> float:
    """Median wall time of one jitted single-state decision (after compile)."""
    fn = jax.jit(policy)
    jax.block_until_ready(fn(state))
    samples = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(state))
        samples.append(time.perf_counter() - t0)
    return float(np.median(samples))


@hydra.main(version_base="1.3", config_path=None, config_name="policy_eval")
def main(cfg) -> None:
    summary, out_dir = run_in_hydra(cfg, run)
    print((out_dir / "basins.md").read_text())
    print(f"evaluation written to {out_dir}")
    del summary


if __name__ == "__main__":
    launch(main)
