"""Fig. 2b and Fig. 11 on the reduced model: PSP phase portraits and a steering walk.

    jaxloco phase-portrait                         # embedded defaults
    jaxloco phase-portrait planner.h=0.95 policy=nominal portrait_steps=12
    jaxloco phase-portrait --multirun planner.xd_apex_nominal=0.15,0.2,0.25

Writes to hydra's run directory: ``phase_portrait.png`` (sagittal parabolas, frontal limit
cycles), ``steering_walk.png`` (footprints, CoM path, CoM states in the local frames) and
``plans.json`` (footsteps, switch and apex times, terminal reasons).
"""

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import hydra
import jax
import jax.numpy as jnp
from omegaconf import OmegaConf

from jaxloco.app import RunConfig, launch, register, run_in_hydra
from jaxloco.config import config_schema, to_params
from jaxloco.planner import (
    PSPParams,
    describe_reason,
    make_lookahead_policy,
    nominal_distance_value,
    plan_steps,
    sample_com_trajectory,
    turn_schedule,
)
from jaxloco.runtime import write_json
from jaxloco.viz import plot_phase_portraits, plot_walk

log = logging.getLogger(__name__)
POLICIES = ("lookahead", "nominal")
PSPParamsConfig = config_schema(PSPParams)


@dataclass
class LookaheadConfig:
    grid_shape: list[int] = field(default_factory=lambda: [9, 9, 11])
    discount: float = 0.9
    state_weights: list[float] = field(default_factory=lambda: [30.0, 1.0, 1.0])
    """Weights of the squared distance to the nominal apex state (y, xd, yd)."""


@dataclass
class PhasePortraitConfig(RunConfig):
    planner: PSPParamsConfig = field(default_factory=PSPParamsConfig)
    policy: str = "lookahead"
    """``lookahead`` (grid search over the action box) or ``nominal`` (a fixed action)."""
    lookahead: LookaheadConfig = field(default_factory=LookaheadConfig)
    nominal_action: list[float] = field(default_factory=lambda: [0.3, 0.2, 0.0])
    portrait_starts: list[Any] = field(
        default_factory=lambda: [
            [0.056, 0.2, 0.0],  # the nominal apex state
            [0.05, 0.39, 0.33],  # pushed left-forward (Fig. 6)
            [0.0, 0.45, -0.2],
            [0.12, 0.12, 0.15],
        ]
    )
    """Apex states (y, xd, yd) the phase portrait starts from."""
    portrait_steps: int = 8
    steering_start: list[float] = field(default_factory=lambda: [0.056, 0.2, 0.0])
    steering_steps: list[int] = field(default_factory=lambda: [12, 5, 12])
    steering_degrees: list[float] = field(default_factory=lambda: [18.8, 0.0, -18.8])
    """Turn schedule: steering_steps[i] steps turning steering_degrees[i] each (Fig. 11:
    12 at +18.8 deg, 5 straight, 12 at -18.8 deg)."""
    samples_per_phase: int = 48
    dpi: int = 150


register("phase_portrait", PhasePortraitConfig)


def make_policy(cfg: PhasePortraitConfig, params: PSPParams):
    if cfg.policy == "lookahead":
        la = cfg.lookahead
        value = nominal_distance_value(params, tuple(la.state_weights))
        return make_lookahead_policy(params, tuple(la.grid_shape), value, la.discount)
    if cfg.policy == "nominal":
        action = jnp.asarray(cfg.nominal_action)
        return lambda state: action.astype(state.dtype)
    raise ValueError(f"policy must be one of {POLICIES}; got {cfg.policy!r}")


def summarize(plan, name: str) -> dict:
    n_safe = int(plan.num_safe_steps)
    out = {
        "safe_steps": n_safe,
        "footsteps": plan.footsteps,
        "headings_deg": jnp.rad2deg(plan.headings),
        "t_switch": plan.t_switch,
        "t_apex": plan.t_apex,
        "actions": plan.actions,
        "apex_states": plan.apex_states,
        "alive": plan.alive,
    }
    if n_safe < plan.alive.shape[0]:
        out["terminal_reason"] = describe_reason(int(plan.reason[n_safe]))
        log.info("%s: terminal at step %d: %s", name, n_safe, out["terminal_reason"])
    else:
        log.info("%s: all %d steps safe", name, n_safe)
    return out


def run(cfg: PhasePortraitConfig, out_dir: Path) -> dict:
    params = to_params(PSPParams, cfg.planner)
    policy = make_policy(cfg, params)
    try:
        starts = jnp.asarray(cfg.portrait_starts, dtype=float)
    except (TypeError, ValueError) as err:
        raise ValueError(f"portrait_starts must be a list of [y, xd, yd]: {err}") from err
    if starts.ndim != 2 or starts.shape[1] != 3:
        raise ValueError(
            f"portrait_starts must be a list of [y, xd, yd]; got {cfg.portrait_starts}"
        )
    if len(cfg.steering_steps) != len(cfg.steering_degrees):
        raise ValueError(
            f"steering_steps ({len(cfg.steering_steps)} entries) and steering_degrees "
            f"({len(cfg.steering_degrees)} entries) must have the same length"
        )
    if cfg.portrait_steps < 1:
        raise ValueError(f"portrait_steps must be >= 1; got {cfg.portrait_steps}")

    # Phase portraits: one batched, jitted multi-step plan over all start states.
    portrait = jax.jit(
        jax.vmap(lambda s: plan_steps(s, policy, params, num_steps=cfg.portrait_steps))
    )(starts)
    trajs = jax.vmap(lambda p: sample_com_trajectory(p, params, cfg.samples_per_phase))(portrait)
    unstack = lambda tree, i: jax.tree.map(lambda x: x[i], tree)  # noqa: E731
    labels = [f"start ({s[0]:.3f}, {s[1]:.2f}, {s[2]:.2f})" for s in cfg.portrait_starts]
    fig = plot_phase_portraits(
        [unstack(trajs, i) for i in range(len(starts))],
        labels,
        title=f"PSP phase portraits, {cfg.policy} policy",
    )
    fig.savefig(out_dir / "phase_portrait.png", dpi=cfg.dpi)

    # Steering walk (Fig. 11).
    segments = list(zip(cfg.steering_steps, cfg.steering_degrees, strict=True))
    turns = turn_schedule(segments)
    walk = jax.jit(lambda s: plan_steps(s, policy, params, num_steps=len(turns), turns=turns))(
        jnp.asarray(cfg.steering_start)
    )
    walk_traj = sample_com_trajectory(walk, params, cfg.samples_per_phase)
    schedule = ", ".join(f"{n} x {d:+.1f} deg" for n, d in segments)
    fig = plot_walk(walk, walk_traj, title=f"steering walk: {schedule} ({cfg.policy} policy)")
    fig.savefig(out_dir / "steering_walk.png", dpi=cfg.dpi)

    summary = {
        "config": OmegaConf.to_container(OmegaConf.structured(cfg)),
        "portraits": [summarize(unstack(portrait, i), labels[i]) for i in range(len(starts))],
        "steering_walk": summarize(walk, "steering walk"),
    }
    write_json(out_dir / "plans.json", summary)
    return summary


@hydra.main(version_base="1.3", config_path=None, config_name="phase_portrait")
def main(cfg) -> None:
    _, out_dir = run_in_hydra(cfg, run)
    print(f"phase portrait and steering walk written to {out_dir}")


if __name__ == "__main__":
    launch(main)
