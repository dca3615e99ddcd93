"""Walking runs on MuJoCo's C engine with the jitted walking controller: the building block
of the walking, steering and push-recovery experiments (one robot, full per-tick logs).

For batches of robots use :mod:`jaxloco.sim.mjx_loop` (MJX) with the same controller.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from jaxloco.dynamics.engine_terms import check_same_dynamics, engine_terms
from jaxloco.locomotion.walking import WalkingController
from jaxloco.locomotion.walking_log import WalkingLog
from jaxloco.sim.mjx_loop import PhysicsParams, physics_model
from jaxloco.sim.mujoco_c import ClosedLoopLog, PackedController, run_closed_loop
from jaxloco.sim.push import Push, PushArrays, apply_push_c, body_index


@dataclasses.dataclass
class WalkRun:
    """A walk on MuJoCo C (:func:`simulate_walk`)."""

    log: ClosedLoopLog[WalkingLog]
    """Every tick of the run."""
    pushes: tuple[Push, ...]
    """The pushes applied."""
    steps_taken: int
    """Steps begun by the end of the run."""
    fell: bool
    """The base dropped below the fall height (or the state went non-finite)."""
    fall_time: float | None
    """Time of the fall (s); None when it did not fall."""


def simulate_walk(
    model: mujoco.MjModel,
    ctrl: WalkingController,
    duration: float,
    turns=None,
    pushes: tuple[Push, ...] = (),
    max_steps: int | None = None,
    physics: PhysicsParams | None = None,
    fall_height: float | None = None,
    progress: bool | str = False,
    step=None,
    watch: Callable[[mujoco.MjModel, mujoco.MjData], Callable[[mujoco.MjData], None]] | None = None,
    engine: bool = True,
) -> WalkRun:
    """Walk from the robot's keyframe for ``duration`` s (or until ``max_steps`` steps have
    begun), turning by ``turns`` (rad per step) and pushed by ``pushes``.

    ``step``: ``PackedController(ctrl.step)`` (:class:`~.mujoco_c.PackedController`) to
    reuse its compiled tick across runs (default: made here, so each call traces again; the
    persistent compile cache saves the compile). ``fall_height``:
    base height (m) that ends the run as a fall (default: the robot's). ``watch(model,
    data)``: opens a view of the run (e.g. :func:`.viewer.open_viewer`) and returns what
    is called after every physics step; its ``close()``, if it has one, runs at the end.
    ``engine``: the controller reads the dynamics MuJoCo C computed for each state
    (:func:`~.mujoco_c.run_closed_loop`'s ``engine``) instead of computing them with MJX;
    ``ctrl`` must then be a controller of ``model`` (checked)."""
    fall_height = ctrl.robot.fall_height if fall_height is None else fall_height
    if duration <= 0:
        raise ValueError(f"duration must be > 0; got {duration}")
    sim_model = physics_model(model, physics) if physics is not None else model
    if engine:
        check_same_dynamics(ctrl.wblc.mx, sim_model)
    data = mujoco.MjData(sim_model)
    data.qpos[:] = ctrl.robot.keyframe_qpos(model)
    mujoco.mj_forward(sim_model, data)
    turns = None if turns is None or len(turns) == 0 else np.asarray(turns)
    init = jax.jit(WalkingController.init, static_argnames="num_turns")
    terms = engine_terms(data) if engine else None
    state = init(ctrl, jnp.asarray(data.qpos), turns=turns, engine=terms)
    rows = PushArrays.of(pushes) if pushes else None
    bodies = {body_index(model, p.body) for p in pushes}
    if len(bodies) > 1:
        raise ValueError("simulate_walk: all pushes must act on the same body")
    body = bodies.pop() if bodies else 0

    def perturb(d):
        if rows is not None:
            apply_push_c(sim_model, d, rows, body)

    done = None if max_steps is None else (lambda log: int(log.step) > max_steps)
    on_step = watch(sim_model, data) if watch is not None else None
    try:
        log, _ = run_closed_loop(
            sim_model,
            data,
            PackedController(ctrl.step) if step is None else step,
            state,
            int(round(duration / model.opt.timestep)),
            stop=lambda d: d.qpos[2] < fall_height,
            progress=progress,
            perturb=perturb,
            done=done,
            on_step=on_step,
            engine=engine,
        )
    finally:
        if hasattr(on_step, "close"):
            on_step.close()
    steps = int(log.outputs.step[-1]) if len(log.time) else 0
    return WalkRun(log, tuple(pushes), steps, log.fell, float(log.time[-1]) if log.fell else None)


def local_com_states(log: ClosedLoopLog[WalkingLog]) -> np.ndarray:
    """Per tick, the CoM state ``(x, xd, y, yd)`` relative to the stance foot in the stance
    frame (x along the step's heading, y mirrored towards the swing side): what Fig. 11b
    and Fig. 12 plot."""
    o = log.outputs
    stance = np.asarray(o.stance)
    foot = np.asarray(o.feet)[np.arange(len(stance)), stance]
    heading = np.asarray(o.heading)
    sign = np.where(stance == 1, 1.0, -1.0)
    c, s = np.cos(heading), np.sin(heading)
    rel = np.asarray(o.com)[:, :2] - foot[:, :2]
    vel = np.asarray(o.com_vel)[:, :2]
    x = c * rel[:, 0] + s * rel[:, 1]
    y = sign * (-s * rel[:, 0] + c * rel[:, 1])
    xd = c * vel[:, 0] + s * vel[:, 1]
    yd = sign * (-s * vel[:, 0] + c * vel[:, 1])
    return np.stack([x, xd, y, yd], axis=1)
