"""Start states of pushed runs: snapshots of undisturbed walks at the pushes' gait phases.

Every push of a sweep starts from the same few undisturbed walks (one per walking speed,
heading change and replanning switch). Each is simulated once, on MuJoCo's C engine with
the jitted walking controller, up to the last push's start; at each requested gait phase of
step ``push_step`` its full physics state (``mjSTATE_INTEGRATION``) and controller state
are kept. Both physics backends then start every pushed run from these snapshots, so they
run the same pushes from the same states, and nobody simulates the walk up to the push
thousands of times.
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from jaxloco.dynamics.engine_terms import engine_terms
from jaxloco.locomotion.gait_params import GaitOverrides
from jaxloco.locomotion.walking import WalkingController, WalkingState

NUM_TURNS = 64
"""Length of the per-step heading-change array every sweep controller gets (a static
shape: one compiled controller serves every heading)."""

STATE_SPEC = mujoco.mjtState.mjSTATE_INTEGRATION


@dataclasses.dataclass
class WalkSnapshots:
    """Snapshots of one undisturbed walk, one per requested phase."""

    phases: np.ndarray
    """(P,) the requested phases of step ``push_step``'s single support."""
    times: np.ndarray
    """Simulated time of each snapshot (s)."""
    physics: np.ndarray
    """(P, nstate) ``mjSTATE_INTEGRATION`` rows."""
    controller: WalkingState
    """Controller states, leading axis P."""
    step_start: float
    """Start of step ``push_step`` (s)."""
    step_duration: float
    """Start and planned duration of step ``push_step`` (s)."""


def save_snapshots(path, snapshots: WalkSnapshots) -> None:
    """Write ``snapshots`` to ``path`` (.npz) atomically: the file is whole or absent."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    leaves = jax.tree.leaves(snapshots.controller)
    tmp = path.with_name(f"{path.stem}.tmp{os.getpid()}.npz")
    np.savez(
        tmp,
        phases=snapshots.phases,
        times=snapshots.times,
        physics=snapshots.physics,
        step=np.asarray([snapshots.step_start, snapshots.step_duration]),
        **{f"controller_{i}": np.asarray(x) for i, x in enumerate(leaves)},
    )
    os.replace(tmp, path)


def load_snapshots(path, controller_template) -> WalkSnapshots:
    """Read what :func:`save_snapshots` wrote; ``controller_template``: any controller
    state of the same structure (e.g. :func:`initial_controller_state`)."""
    treedef = jax.tree.structure(controller_template)
    with np.load(path) as f:
        leaves = [f[f"controller_{i}"] for i in range(treedef.num_leaves)]
        step_start, step_duration = (float(x) for x in f["step"])
        return WalkSnapshots(
            f["phases"],
            f["times"],
            f["physics"],
            jax.tree.unflatten(treedef, leaves),
            step_start,
            step_duration,
        )


def kept_phases(path) -> set[float]:
    """The phases of the walk kept at ``path`` (empty when there is none)."""
    path = Path(path)
    if not path.exists():
        return set()
    with np.load(path) as f:
        return set(f["phases"].tolist())


def walk_key(apex_speed: float, turn_deg: float, replan: bool) -> tuple:
    return (round(float(apex_speed), 9), round(float(turn_deg), 9), bool(replan))


def initial_controller_state(
    ctrl: WalkingController, model: mujoco.MjModel, apex_speed, turn_deg, replan
):
    data = mujoco.MjData(model)
    data.qpos[:] = ctrl.robot.keyframe_qpos(model)
    mujoco.mj_forward(model, data)
    qpos = jnp.asarray(data.qpos)
    turns = np.full(NUM_TURNS, math.radians(turn_deg))
    overrides = GaitOverrides.of(
        ctrl.gait_params, jnp.asarray(qpos).dtype, replan=bool(replan), apex_speed=apex_speed
    )
    init = jax.jit(WalkingController.init, static_argnames="num_turns")
    return init(ctrl, qpos, turns=turns, overrides=overrides, engine=engine_terms(data))


def snapshot_walk(
    sim_model: mujoco.MjModel,
    ctrl: WalkingController,
    step_fn,
    apex_speed: float,
    turn_deg: float,
    replan: bool,
    push_step: int,
    phases,
    fall_height: float = 0.7,
    max_time: float = 30.0,
) -> WalkSnapshots:
    """Walk undisturbed until every phase of step ``push_step`` has been reached.

    ``step_fn`` is the jitted ``ctrl.step``, given what MuJoCo C computed for each state
    (its ``engine``; each physics step is ``mj_step1``, the controller, ``mj_step2``).
    Raises ``RuntimeError`` when the undisturbed walk falls first: a sweep from a walk that
    cannot walk measures nothing.
    """
    phases = np.asarray(sorted(set(float(p) for p in phases)))
    data = mujoco.MjData(sim_model)
    data.qpos[:] = ctrl.robot.keyframe_qpos(sim_model)
    mujoco.mj_forward(sim_model, data)
    cstate = initial_controller_state(ctrl, sim_model, apex_speed, turn_deg, replan)
    blend = ctrl.gait_params.contact_blend
    dt = sim_model.opt.timestep
    push_times = None
    step_start = step_duration = None
    kept_times, rows, cstates = [], [], []
    state_size = mujoco.mj_stateSize(sim_model, STATE_SPEC)
    while len(rows) < len(phases):
        if data.time > max_time:
            raise RuntimeError(
                f"undisturbed walk (apex speed {apex_speed}, turn {turn_deg} deg) did not "
                f"reach step {push_step} in {max_time} s"
            )
        if push_times is not None:
            while len(rows) < len(phases) and data.time >= push_times[len(rows)] - 0.5 * dt:
                row = np.empty(state_size)
                mujoco.mj_getState(sim_model, data, row, STATE_SPEC)
                rows.append(row)
                cstates.append(cstate)
                kept_times.append(data.time)
            if len(rows) == len(phases):
                break
        mujoco.mj_step1(sim_model, data)  # with mj_step2 below: mj_step
        terms = engine_terms(data)
        torques, cstate, log = step_fn(data.time, terms.qpos, terms.qvel, cstate, engine=terms)
        data.ctrl[:] = np.asarray(torques)
        if push_times is None and int(log.step) == push_step:
            step_start = float(cstate.gait.step_start)
            step_duration = float(cstate.gait.step_duration)
            support = step_duration - blend
            push_times = step_start + blend + phases * support
        mujoco.mj_step2(sim_model, data)
        if data.qpos[2] < fall_height or not np.all(np.isfinite(data.qpos)):
            raise RuntimeError(
                f"undisturbed walk (apex speed {apex_speed}, turn {turn_deg} deg, replan "
                f"{replan}) fell at t = {data.time:.2f} s before step {push_step}"
            )
    controller = jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *cstates)
    return WalkSnapshots(
        phases, np.asarray(kept_times), np.stack(rows), controller, step_start, step_duration
    )


def gather_starts(table, row_ids, snapshots: dict, qvel_noise: float, nq: int, nv: int):
    """Start states of the push rows ``row_ids`` of ``table``: (times, physics rows,
    controller states), each with a leading axis over the rows.

    Each row starts from its walk's snapshot nearest its phase, with its replanning switch,
    plus joint-velocity noise when ``qvel_noise`` > 0, drawn from the row's seed and index
    (so a row's start never depends on how the sweep is chunked).
    """
    times, physics, cstates = [], [], []
    for row in row_ids:
        key = walk_key(table["apex_speed"][row], table["turn_deg"][row], table["replan"][row])
        snap = snapshots[key]
        k = int(np.argmin(np.abs(snap.phases - table["phase"][row])))
        phys = snap.physics[k].copy()
        if qvel_noise > 0:
            rng = np.random.default_rng([int(table["seed"][row]), int(row)])
            # mjSTATE_INTEGRATION is laid out as time, qpos (nq), qvel (nv), ...
            phys[1 + nq : 1 + nq + nv] += rng.normal(0.0, qvel_noise, nv)
        times.append(snap.times[k])
        physics.append(phys)
        cstates.append(jax.tree.map(lambda x, k=k: x[k], snap.controller))
    controller = jax.tree.map(lambda *xs: np.stack(xs), *cstates)
    return np.asarray(times), np.stack(physics), controller
