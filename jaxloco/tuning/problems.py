"""Tuning problems: a differentiable loss of the tuned gains, built from a rollout.

:func:`shaking_loss` is the body-shaking task of Fig. 10: Valkyrie in double support, the
body frame following :func:`~jaxloco.control.shaking.shaking_reference`, optionally pushed
on the pelvis (robustness: a batch of pushes is averaged). Its loss is

    w_track * mean |e_body|^2  +  w_effort * mean |tau|^2 / tau_scale^2
    + w_com * mean |com_xy - com_xy(0)|^2  +  w_slip * mean |p_xy - p_xy(0)|^2
    + w_fall * fraction of ticks fallen

with every mean over time and over the batch of pushes (``p``: the feet's contact points,
averaged over the points). The CoM term is the smooth surrogate of falling that push recovery asks
for (a pushed robot that falls first drifts away); the slip term catches the slow creep of
the feet under the shaking's oscillating loads, which stiffer body gains speed up and which
degrades tracking (or ends in a fall) seconds later, beyond any horizon that is affordable
to differentiate (see ``docs/tuning.md``).
``fallen`` itself has zero gradient and is there so a fall never looks like a good value.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from jaxloco import validation as v
from jaxloco.control.presets import body_shaking_config
from jaxloco.control.shaking import ShakingParams, shaking_reference
from jaxloco.control.wblc import make_wblc
from jaxloco.dynamics.engine_terms import check_same_dynamics
from jaxloco.dynamics.model import keyframe_qpos
from jaxloco.dynamics.quiet_mjx import mjx
from jaxloco.locomotion.gait import com_reference
from jaxloco.sim.mjx_loop import loop_state_from_c
from jaxloco.sim.push import PushArrays, body_index
from jaxloco.sweep.backends import ChunkStarts, mjx_loop_states
from jaxloco.sweep.starts import snapshot_walk
from jaxloco.tuning.gains import GainSpace
from jaxloco.tuning.rollout import check_differentiable, depend_on, mean_costs


@dataclasses.dataclass(frozen=True)
class ShakingLossParams:
    """The body-shaking tuning problem: what is simulated and how it is scored."""

    hierarchy: str = "H1"
    """Eq. 32's H1 (stable in our reproduction) or H2 (its 5 s shaking diverges, and tuning
    its body gains does not fix that)."""
    horizon: float = 1.0
    """Simulated seconds per loss evaluation."""
    segment: int = 1
    """Ticks per checkpointed segment (memory vs recompute, see :mod:`.rollout`), >= 1.
    Reverse mode only; 1 because XLA:CPU compiles longer segments' reverse pass far more
    slowly."""
    pinv_rtol: float = 1e-2
    """The hierarchy's rank threshold (as in ``experiments/body_shaking.py``)."""
    frequencies: tuple[float, ...] = ()
    """Shaking frequencies (Hz) the loss averages over, one rollout per frequency and push;
    empty: the shaking's own ``frequency_hz`` only. Gains tuned at one frequency overfit
    it."""
    track_weight: float = 1.0
    """Weight of the body orientation's squared error (rad^2)."""
    effort_weight: float = 0.01
    """Weight of the squared torque norm in units of ``torque_scale``."""
    torque_scale: float = 300.0
    """Torque scale (N m) of the effort term, which is then O(1) near standing."""
    com_weight: float = 10.0
    """Weight of the CoM's horizontal drift squared (m^2)."""
    slip_weight: float = 0.0
    """Weight of the feet's creep (m^2 of contact-point displacement, time-averaged). 0 by
    default: at 100 the gains stiffened and the feet crept more on MuJoCo C, at 1000 the
    gains softened until tracking got worse (docs/tuning.md)."""
    fall_weight: float = 10.0
    """Weight of the fraction of the horizon spent fallen."""
    fall_height: float = 0.7
    """Base height (m) below which the robot has fallen."""

    def __post_init__(self):
        v.check_fields(
            self,
            [
                *v.positive(self, "horizon", "torque_scale"),
                *v.non_negative(
                    self,
                    "track_weight",
                    "effort_weight",
                    "com_weight",
                    "slip_weight",
                    "fall_weight",
                ),
                v.integer(self, "segment", 1),
                ("frequencies", all(0 < f <= 10 for f in self.frequencies), "in (0, 10] Hz"),
            ],
        )


def horizon_steps(model: mujoco.MjModel, params: ShakingLossParams) -> int:
    """Ticks of the horizon, rounded up to a whole number of segments."""
    steps = int(round(params.horizon / model.opt.timestep))
    return max(params.segment, -(-steps // params.segment) * params.segment)


def shaking_loss(
    model: mujoco.MjModel,
    space: GainSpace,
    params: ShakingLossParams = ShakingLossParams(),
    shaking: ShakingParams = ShakingParams(),
):
    """``(loss_fn, init_params, base_gains)``.

    ``loss_fn(gain_params, pushes) -> (loss, costs)``: ``pushes`` is a
    :class:`~jaxloco.sim.push.PushArrays` of shape ``(B,)`` on the pelvis (world frame, times
    from the start of the shaking), one rollout per push and frequency of
    ``params.frequencies`` (:meth:`~jaxloco.sim.push.PushArrays.none` for no push);
    ``costs`` holds each term averaged over the batch. ``model`` must be a physics model
    with one solver iteration (:func:`~jaxloco.tuning.rollout.tuning_physics`).
    """
    check_differentiable(model)
    ctrl = make_wblc(model, body_shaking_config(params.hierarchy, pinv_rtol=params.pinv_rtol))
    mx = ctrl.mx
    data0 = mujoco.MjData(model)
    data0.qpos[:] = keyframe_qpos(model, "walk")
    mujoco.mj_forward(model, data0)
    qpos0 = jnp.asarray(data0.qpos)
    # From MuJoCo C: no forward pass to trace into the loss (docs/architecture.md,
    # measured choices).
    refs0 = ctrl.hold_references_at(model, qpos0)
    state0 = loop_state_from_c(mx, model, data0, ctrl.initial_qp_state())
    com0 = jnp.asarray(data0.subtree_com[0])
    points = jnp.asarray(ctrl.point_sites)
    points0 = jnp.asarray(data0.site_xpos[np.asarray(ctrl.point_sites), :2])
    contact = jnp.ones(2)
    base = ctrl.default_gains()
    steps = horizon_steps(model, params)
    pelvis = body_index(model, "pelvis")
    frequencies = params.frequencies or (shaking.frequency_hz,)

    def loss_fn(gain_params, pushes):
        gains = space.gains(gain_params, base)
        dtype = jax.tree.leaves(gain_params)[0].dtype
        q0 = refs0["body_ori"].pos.astype(dtype)

        def controller(t, qpos, qvel, prev, frequency, engine):
            quat, vel, acc = shaking_reference(shaking, q0, t, frequency)
            refs = {**refs0, "body_ori": refs0["body_ori"].replace(pos=quat, vel=vel, acc=acc)}
            snap = ctrl.snapshot(qpos, qvel, engine)  # the physics' own terms of the state
            out = ctrl(qpos, qvel, refs, contact, gains=gains, previous=prev, snap=snap)
            err = out.diagnostics.task_errors["body_ori"]
            com = snap.com[:2]
            costs = {
                "track": err @ err,
                "effort": (out.torques @ out.torques) / params.torque_scale**2,
                "com": jnp.sum((com - com0[:2].astype(dtype)) ** 2),
                "slip": jnp.mean(
                    jnp.sum((snap.data.site_xpos[points, :2] - points0.astype(dtype)) ** 2, -1)
                ),
            }
            return out.torques, out.qp_state, costs

        def one(push, frequency, state):
            final, costs = mean_costs(
                mx,
                lambda t, q, v, prev, engine: controller(t, q, v, prev, frequency, engine),
                state,
                steps,
                params.segment,
                push,
                pelvis,
                params.fall_height,
            )
            # Fraction of the horizon spent fallen (fall_time is inf while standing).
            duration = steps * model.opt.timestep
            fallen = jnp.where(final.fell, 1.0 - final.fall_time / duration, 0.0)
            costs["fallen"] = fallen.astype(dtype)
            return costs

        # One batch of every (push, frequency) pair, each rollout from its own copy of the
        # start state: a scan whose carry starts batched is vmapped in one pass over the
        # tick, so the loss traces the tick once (docs/architecture.md, measured choices).
        n_push, n_freq = pushes.magnitude.shape[0], len(frequencies)
        pairs_push = jax.tree.map(lambda x: jnp.repeat(x, n_freq, axis=0), pushes)
        pairs_freq = jnp.tile(jnp.asarray(frequencies, dtype), n_push)
        states = jax.tree.map(
            lambda x: jnp.broadcast_to(_as_float(x, dtype), (n_push * n_freq, *x.shape)), state0
        )
        states = depend_on(states, gain_params)
        batch = jax.vmap(one)(pairs_push, pairs_freq, states)
        costs = jax.tree.map(lambda v: jnp.mean(v, axis=0), batch)
        loss = (
            params.track_weight * costs["track"]
            + params.effort_weight * costs["effort"]
            + params.com_weight * costs["com"]
            + params.slip_weight * costs["slip"]
            + params.fall_weight * costs["fallen"]
        )
        return loss, costs

    return loss_fn, space.init(base), base


@dataclasses.dataclass(frozen=True)
class PushLossParams:
    """The walking push-recovery tuning problem: Valkyrie walks, is pushed during single
    support, and is scored on how far it is thrown off over the next ``horizon`` seconds.

    Per push, averaged over the batch of pushes::

        w_risk * sigmoid(log(dcm / risk_threshold) / risk_temperature)
        + w_dcm * dcm + w_tilt * tilt + w_effort * |tau_applied|^2 / tau_scale^2
        + w_fall * fraction of the horizon fallen

    with ``dcm``, ``tilt`` and the effort averaged over the horizon's ticks. The first
    term is a smooth count of the pushes likely to end in a fall: ``dcm`` spans four
    decades over pushes and a mean of it follows the few hopeless ones, while whether a
    push is recovered turns on whether it is above a threshold (on MuJoCo C the soft count
    ranked replan gammas as the recovered counts did, the mean of ``dcm`` did not; see
    ``docs/tuning.md``).

    ``xi = c + c_dot / omega`` is the CoM's horizontal divergent component (capture point).
    What it is compared with (``dcm_reference``):

    - ``"footstep"`` (default): ``xi`` is carried by the LIPM about the stance foot to the
      step's current touch-down time and measured from the footstep the swing foot is
      heading to, both as replanned; the term is that offset's squared distance from the
      pre-push plan's own offset at its touch-down. It asks whether the step the robot is
      taking will catch it as the undisturbed step would have, so a replan that moves the
      footstep to where the push sent the capture point scores well, and one that leaves
      the plan unchanged does not.
    - ``"plan"``: ``xi_plan`` is the capture point of the step as planned before the push,
      at the same time: how far the push threw the robot off that plan. It penalises
      leaving the old plan, which recovery needs: it can rise while more pushes are
      recovered.

    ``tilt`` is the squared change of the pelvis's up axis since the push began. Both are
    smooth surrogates of falling, and neither rewards moving the CoM reference (Eq. 33's
    error would: it is zero right after a replan from the measured state).
    """

    horizon: float = 0.25
    """Simulated seconds from the push's start; keep it before the step's touch-down, after
    which the pre-push plan is no reference. Gradients are trustworthy up to the
    touch-down, not across it (docs/tuning.md)."""
    dcm_reference: str = "footstep"
    """``"footstep"`` or ``"plan"`` (see above)."""
    push_step: int = 4
    """The step (from the first lift-off) during whose single support the pushes start."""
    phase: float = 0.3
    """Fraction of that single support at which they start."""
    apex_speed: float = 1.0
    """Walking speed cap (``GaitParams.max_apex_speed``; >= 0.37: the policy's own)."""
    segment: int = 1
    """Ticks per checkpointed segment (reverse mode only, see :mod:`.rollout`)."""
    risk_weight: float = 10.0
    """Weight of the soft count of pushes at risk (see the class doc)."""
    risk_threshold: float = 0.02
    """``dcm`` (m^2) at which a push counts as half lost (see above)."""
    risk_temperature: float = 0.5
    """Width of the soft count's step in ``log(dcm)``."""
    dcm_weight: float = 0.0
    """The mean of ``dcm`` itself (100 with ``dcm_reference="plan"`` is a tested setting)."""
    tilt_weight: float = 10.0
    """Weight of the body's tilt squared (rad^2)."""
    effort_weight: float = 0.001
    """Small: the effort term is about 6 (mean of 8 pushes of 650 N over 0.25 s, torques
    clipped to the 500 N m limits, ``torque_scale`` 300)."""
    torque_scale: float = 300.0
    """Torque scale (N m) of the effort term."""
    fall_weight: float = 10.0
    """Weight of the fraction of the horizon spent fallen."""
    fall_height: float = 0.7
    """Base height (m) below which the robot has fallen."""

    def __post_init__(self):
        v.check_fields(
            self,
            [
                *v.positive(
                    self,
                    "horizon",
                    "torque_scale",
                    "apex_speed",
                    "risk_threshold",
                    "risk_temperature",
                ),
                *v.non_negative(
                    self,
                    "risk_weight",
                    "dcm_weight",
                    "tilt_weight",
                    "effort_weight",
                    "fall_weight",
                ),
                *v.unit_interval(self, "phase"),
                v.one_of(self, "dcm_reference", ("footstep", "plan")),
                v.integer(self, "push_step", 1),
                v.integer(self, "segment", 1),
            ],
        )


def push_loss(
    sim_model: mujoco.MjModel,
    ctrl,
    space: GainSpace,
    params: PushLossParams = PushLossParams(),
    push_body: str = "pelvis",
):
    """``(loss_fn, init_params, base_gains)`` of the walking push-recovery problem.

    ``ctrl``: a :class:`~jaxloco.locomotion.walking.WalkingController`; ``sim_model``: the
    simulated physics (e.g. :func:`~jaxloco.sim.mjx_loop.physics_model`; reverse-mode
    gradients need :func:`~jaxloco.tuning.rollout.tuning_physics`, forward mode does not).
    The undisturbed walk up to the push is simulated once, on MuJoCo C, as the sweeps do
    (:func:`~jaxloco.sweep.starts.snapshot_walk`); every loss evaluation starts there.

    ``loss_fn(tuned, pushes) -> (loss, costs)``: ``pushes`` is a
    :class:`~jaxloco.sim.push.PushArrays` of shape ``(B,)``, one MJX rollout each, in the
    walking frame at the push: ``direction`` from the heading (0: forward) and ``start``
    in s after the push instant (``params.phase`` of step ``params.push_step``; 0: at it).
    ``space`` may name WBLC gains and ``"gait.replan_gamma"``.
    """
    base = ctrl.wblc.default_gains()
    space.check(base)
    check_same_dynamics(ctrl.wblc.mx, sim_model)  # the controller reads the engine's terms
    base_gait = dataclasses.asdict(ctrl.gait_params)
    snaps = snapshot_walk(
        sim_model, ctrl, jax.jit(ctrl.step), params.apex_speed, 0.0, True, params.push_step,
        [params.phase], params.fall_height,
    )  # fmt: skip
    starts = ChunkStarts(snaps.times, snaps.physics, snaps.controller, PushArrays.none())
    state0 = jax.tree.map(lambda x: x[0], mjx_loop_states(sim_model, starts))
    mx = mjx.put_model(sim_model)
    t0 = float(snaps.times[0])
    heading = float(np.asarray(snaps.controller.gait.heading)[0])
    steps = int(round(params.horizon / sim_model.opt.timestep))
    steps = max(params.segment, -(-steps // params.segment) * params.segment)
    body = body_index(sim_model, push_body)
    up0 = _pelvis_up(state0.data.qpos[3:7])  # the walk's own tilt at the push is not a cost
    plan0 = state0.controller.gait  # the step as planned before the push
    limited = sim_model.actuator_ctrllimited.astype(bool)
    lo = np.where(limited, sim_model.actuator_ctrlrange[:, 0], -np.inf)
    hi = np.where(limited, sim_model.actuator_ctrlrange[:, 1], np.inf)
    omega = ctrl.psp.omega
    # The pre-push plan's capture point at its touch-down, relative to its footstep.
    t_td0 = plan0.step_start + plan0.step_duration
    ref_pos, ref_vel, _ = com_reference(plan0, ctrl.gait_params, ctrl.psp, t_td0)
    offset0 = ref_pos[:2] + ref_vel[:2] / omega - plan0.target[:2]

    def loss_fn(tuned, pushes):
        gains = space.gains(tuned, base)
        gait_values = space.gait_values(tuned, base_gait)
        dtype = state0.data.qpos.dtype

        def controller(t, qpos, qvel, cstate, engine):
            torques, cstate, log = ctrl.step(t, qpos, qvel, cstate, gains=gains, engine=engine)
            up = _pelvis_up(qpos[3:7])
            dcm = log.com[:2] + log.com_vel[:2] / omega
            if params.dcm_reference == "footstep":
                dcm_error = _touchdown_dcm_offset(cstate.gait, dcm, t, omega) - offset0
            else:
                ref_pos, ref_vel, _ = com_reference(plan0, ctrl.gait_params, ctrl.psp, t)
                dcm_error = dcm - ref_pos[:2] - ref_vel[:2] / omega
            costs = {
                "dcm": jnp.sum(dcm_error.astype(dcm.dtype) ** 2),
                "tilt": jnp.sum((up - up0.astype(up.dtype)) ** 2),
                # The torques the actuators apply: the WBLC's own can spike far past the
                # limits for a tick, which swamped the loss.
                "effort": jnp.sum(jnp.clip(torques, lo, hi) ** 2) / params.torque_scale**2,
            }
            return torques, cstate, costs

        def one(push, start):
            gait = start.controller.gait
            overrides = gait.overrides.replace(
                **{k: jnp.asarray(v, dtype) for k, v in gait_values.items()}
            )
            gait = gait.replace(overrides=overrides)
            state = start.replace(controller=start.controller.replace(gait=gait))
            world = push._replace(direction=heading + push.direction, start=t0 + push.start)
            final, costs = mean_costs(
                mx, controller, state, steps, params.segment, world.astype(dtype), body,
                params.fall_height,
            )  # fmt: skip
            duration = steps * sim_model.opt.timestep
            fallen = jnp.where(final.fell, 1.0 - (final.fall_time - t0) / duration, 0.0)
            costs["fallen"] = fallen.astype(dtype)
            excess = (
                jnp.log(jnp.maximum(costs["dcm"], 1e-12) / params.risk_threshold)
                / params.risk_temperature
            )
            costs["at_risk"] = jax.nn.sigmoid(excess)
            return costs

        # Each rollout from its own copy of the start state (see the shaking problem).
        states = jax.tree.map(
            lambda x: jnp.broadcast_to(x, pushes.magnitude.shape[:1] + x.shape), state0
        )
        states = depend_on(states, tuned)
        costs = jax.tree.map(lambda v: jnp.mean(v, axis=0), jax.vmap(one)(pushes, states))
        loss = (
            params.risk_weight * costs["at_risk"]
            + params.dcm_weight * costs["dcm"]
            + params.tilt_weight * costs["tilt"]
            + params.effort_weight * costs["effort"]
            + params.fall_weight * costs["fallen"]
        )
        return loss, costs

    return loss_fn, space.init(base), base


def _as_float(x, dtype):
    """``x`` in ``dtype`` if it is a floating-point array, else unchanged."""
    return x.astype(dtype) if jnp.issubdtype(x.dtype, jnp.floating) else x


def _touchdown_dcm_offset(gait, dcm, t, omega):
    """The capture point ``dcm`` (2,) carried by the LIPM about the stance foot to the
    step's planned touch-down (``xi' = omega (xi - p)``), minus the footstep it lands on.
    After the touch-down (the horizon may reach into the next step) it is the next
    step's, which its pre-push offset does not describe: keep the horizon short of it."""
    stance = gait.stance_pos[:2]
    remaining = jnp.maximum(gait.step_start + gait.step_duration - t, 0.0)
    at_touchdown = stance + (dcm - stance) * jnp.exp(omega * remaining)
    return at_touchdown - gait.target[:2]


def _pelvis_up(quat):
    """The floating base's z axis in world coordinates, from its (w, x, y, z) quaternion."""
    w, x, y, z = quat / jnp.linalg.norm(quat)
    return jnp.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)])
