"""Body shaking (Fig. 10) on MuJoCo's C engine: Valkyrie in double support under WBLC, its
body frame following :func:`~jaxloco.control.shaking.shaking_reference`.

Used by ``experiments/body_shaking.py`` (H1 vs H2) and by gain tuning as its held-out
measure (tuning runs in MJX with one solver iteration; this runs MuJoCo's default solver).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from jaxloco.control.shaking import ShakingParams, shaking_reference
from jaxloco.control.wblc import WBLCConfig, make_wblc
from jaxloco.dynamics.model import keyframe_qpos
from jaxloco.sim.mujoco_c import ClosedLoopLog, run_closed_loop


def simulate_shaking(
    model: mujoco.MjModel,
    config: WBLCConfig,
    shaking: ShakingParams,
    duration: float,
    fall_height: float = 0.7,
    progress: bool | str = False,
) -> ClosedLoopLog:
    """Shake for ``duration`` s from the ``walk`` keyframe; logs ``body_error`` (rad),
    ``foot_slip`` (m, the largest horizontal displacement of a foot contact point from its
    start), ``torque_norm`` (N m), ``relaxed`` and ``over_limit`` every tick."""
    if duration <= 0:
        raise ValueError(f"simulate_shaking: duration must be > 0 s; got {duration}")
    ctrl = make_wblc(model, config)
    data = mujoco.MjData(model)
    data.qpos[:] = keyframe_qpos(model, "walk")
    mujoco.mj_forward(model, data)
    refs0 = ctrl.hold_references(jnp.asarray(data.qpos))
    q0 = refs0["body_ori"].pos
    contact = jnp.ones(2)
    points = jnp.asarray(ctrl.point_sites)
    points0 = jnp.asarray(data.site_xpos[np.asarray(ctrl.point_sites), :2])

    @jax.jit
    def controller(t, qpos, qvel, prev):
        quat, vel, acc = shaking_reference(shaking, q0, t)
        refs = {**refs0, "body_ori": refs0["body_ori"].replace(pos=quat, vel=vel, acc=acc)}
        snap = ctrl.snapshot(qpos, qvel)
        out = ctrl(qpos, qvel, refs, contact, previous=prev, snap=snap)
        dg = out.diagnostics
        slip = snap.data.site_xpos[points, :2] - points0.astype(snap.data.site_xpos.dtype)
        logged = {
            "body_error": jnp.linalg.norm(dg.task_errors["body_ori"]),
            "foot_slip": jnp.max(jnp.linalg.norm(slip, axis=-1)),
            "torque_norm": jnp.linalg.norm(out.torques),
            "relaxed": dg.qp_relaxed,
            "over_limit": jnp.any(dg.torque_over_limit),
        }
        return out.torques, out.qp_state, logged

    steps = int(round(duration / model.opt.timestep))
    log, _ = run_closed_loop(
        model,
        data,
        controller,
        ctrl.initial_qp_state(),
        steps,
        stop=lambda d: d.qpos[2] < fall_height,
        progress=progress,
    )
    return log


def shaking_metrics(log: ClosedLoopLog) -> dict:
    """RMS and max body error, final foot slip, mean and max torque norm, QP relaxations,
    falls."""
    out = log.outputs
    return {
        "final_foot_slip_m": float(out["foot_slip"][-1]),
        "fell": bool(log.fell),
        "simulated_s": float(log.time[-1]) if len(log.time) else 0.0,
        "rms_body_error_rad": float(np.sqrt(np.mean(out["body_error"] ** 2))),
        "max_body_error_rad": float(np.max(out["body_error"])),
        "mean_torque_norm_Nm": float(np.mean(out["torque_norm"])),
        "max_torque_norm_Nm": float(np.max(out["torque_norm"])),
        "qp_relaxed_ticks": int(np.sum(out["relaxed"])),
        "torque_over_limit_ticks": int(np.sum(out["over_limit"])),
    }
