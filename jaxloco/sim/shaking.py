"""Body shaking (Fig. 10) on MuJoCo's C engine: a humanoid in double support under WBLC, its
body frame following :func:`~jaxloco.control.shaking.shaking_reference`.

Used by ``experiments/body_shaking.py`` (H1 vs H2) and by gain tuning as its held-out
measure (tuning runs in MJX with one solver iteration; this runs MuJoCo's default solver).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from jaxloco.control.shaking import ShakingParams, shaking_reference
from jaxloco.control.wblc import WBLCConfig, make_wblc
from jaxloco.robots import DEFAULT_ROBOT, RobotDescription
from jaxloco.sim.mujoco_c import ClosedLoopLog, PackedController, run_closed_loop


@struct.dataclass
class ShakingLog:
    """One tick of body shaking (stacked over time in a run's ``outputs``)."""

    body_error: jax.Array
    """() norm of the body orientation task's error (rad)."""
    foot_slip: jax.Array
    """() the largest horizontal displacement of a foot contact point from its start (m)."""
    torque_norm: jax.Array
    """() Euclidean norm of the joint torques (N m)."""
    relaxed: jax.Array
    """() bool, the force QP relaxed its friction cone this tick."""
    over_limit: jax.Array
    """() bool, some joint torque exceeded its effort limit this tick."""


def simulate_shaking(
    model: mujoco.MjModel,
    config: WBLCConfig,
    shaking: ShakingParams,
    duration: float,
    fall_height: float | None = None,
    progress: bool | str = False,
    gains: dict | None = None,
    robot: RobotDescription = DEFAULT_ROBOT,
) -> ClosedLoopLog[ShakingLog]:
    """Shake ``robot`` for ``duration`` s from its keyframe, logging a :class:`ShakingLog`
    every tick.

    ``gains``: the WBLC gains pytree (default: ``config``'s). For many runs that differ
    only in gains or frequency, build one :func:`shaking_simulator` instead."""
    simulate = shaking_simulator(model, config, shaking, fall_height, robot)
    return simulate(duration, gains=gains, progress=progress)


def shaking_simulator(
    model: mujoco.MjModel,
    config: WBLCConfig,
    shaking: ShakingParams,
    fall_height: float | None = None,
    robot: RobotDescription = DEFAULT_ROBOT,
):
    """``simulate(duration, gains=None, frequency_hz=None, progress=False) -> ClosedLoopLog``,
    as :func:`simulate_shaking`. The gains and the frequency (default: ``shaking``'s) are
    arguments of one compiled controller, so runs that differ only in them (tuning's
    validation, held-out frequencies) share the compile and the set-up. ``fall_height``
    (m): base height that ends a run as a fall (default: the robot's)."""
    fall_height = robot.fall_height if fall_height is None else fall_height
    ctrl = make_wblc(model, config)
    data0 = mujoco.MjData(model)
    data0.qpos[:] = robot.keyframe_qpos(model)
    mujoco.mj_forward(model, data0)
    # From MuJoCo C's kinematics: no tracing (MJX's, op by op, is hundreds of compiles).
    refs0 = ctrl.hold_references_at(model, data0.qpos)
    q0 = refs0["body_ori"].pos
    contact = jnp.ones(2)
    points = jnp.asarray(ctrl.point_sites)
    points0 = jnp.asarray(data0.site_xpos[np.asarray(ctrl.point_sites), :2])
    default_gains = ctrl.default_gains()

    @jax.jit
    def step(t, qpos, qvel, prev, gains, frequency, engine):
        quat, vel, acc = shaking_reference(shaking, q0, t, frequency)
        refs = {**refs0, "body_ori": refs0["body_ori"].replace(pos=quat, vel=vel, acc=acc)}
        snap = ctrl.snapshot(qpos, qvel, engine)  # what MuJoCo C computed for the state
        out = ctrl(qpos, qvel, refs, contact, gains=gains, previous=prev, snap=snap)
        dg = out.diagnostics
        slip = snap.data.site_xpos[points, :2] - points0.astype(snap.data.site_xpos.dtype)
        logged = ShakingLog(
            body_error=jnp.linalg.norm(dg.task_errors["body_ori"]),
            foot_slip=jnp.max(jnp.linalg.norm(slip, axis=-1)),
            torque_norm=jnp.linalg.norm(out.torques),
            relaxed=dg.qp_relaxed,
            over_limit=jnp.any(dg.torque_over_limit),
        )
        return out.torques, out.qp_state, logged

    def tick(t, qpos, qvel, carry, engine):
        # The gains and the frequency ride in the carry: arguments of the compiled tick,
        # not constants baked into it.
        prev, gains, frequency = carry
        torques, qp_state, logged = step(t, qpos, qvel, prev, gains, frequency, engine)
        return torques, (qp_state, gains, frequency), logged

    controller = PackedController(tick)

    def simulate(duration, gains=None, frequency_hz=None, progress=False) -> ClosedLoopLog:
        if duration <= 0:
            raise ValueError(f"simulate_shaking: duration must be > 0 s; got {duration}")
        # One dtype and structure for every call, so calls share the compiled program.
        dtype = jnp.result_type(float)
        g = jax.tree.map(lambda x: jnp.asarray(x, dtype), default_gains if gains is None else gains)
        f = jnp.asarray(shaking.frequency_hz if frequency_hz is None else frequency_hz, dtype)
        data = mujoco.MjData(model)
        data.qpos[:] = data0.qpos
        mujoco.mj_forward(model, data)
        log, _ = run_closed_loop(
            model,
            data,
            controller,
            (ctrl.initial_qp_state(dtype), g, f),
            int(round(duration / model.opt.timestep)),
            stop=lambda d: d.qpos[2] < fall_height,
            progress=progress,
            engine=True,
        )
        return log

    return simulate


def shaking_metrics(log: ClosedLoopLog[ShakingLog]) -> dict:
    """RMS and max body error, final foot slip, mean and max torque norm, QP relaxations,
    falls."""
    out = log.outputs
    return {
        "final_foot_slip_m": float(out.foot_slip[-1]),
        "fell": bool(log.fell),
        "simulated_s": float(log.time[-1]) if len(log.time) else 0.0,
        "rms_body_error_rad": float(np.sqrt(np.mean(out.body_error**2))),
        "max_body_error_rad": float(np.max(out.body_error)),
        "mean_torque_norm_Nm": float(np.mean(out.torque_norm)),
        "max_torque_norm_Nm": float(np.max(out.torque_norm)),
        "qp_relaxed_ticks": int(np.sum(out.relaxed)),
        "torque_over_limit_ticks": int(np.sum(out.over_limit)),
    }
