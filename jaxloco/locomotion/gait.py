"""The walking state machine: phases, contact blending, step planning and replanning.

Pure JAX state (:class:`GaitState`) advanced once per control tick by :func:`advance`
(paper Section V-B/C). Phases:

- ``START``: double support. The CoM follows a quintic from where it stands to the first
  lift-off state: over the first stance foot's apex (``x = 0``), ``start_lateral`` towards
  the other foot, moving forward at ``start_speed`` and accelerating as the LIPM does there.
- ``WALK``: one single-support step after another. A step begins at a touch-down (or at
  the first lift-off): the new stance foot's contact blends in and the old one's blends out
  over ``contact_blend`` seconds (the force QP's normal-force bound ramps, Section III),
  then the old stance foot swings (:mod:`.swing`: B-spline height, quintic ground path)
  to the planned footstep and lands at the planned switch time, which begins the next step.

**Planning.** At the start of each step, the desired CoM state is expressed in the new
stance frame (origin at the stance foot, x along the step's heading, y mirrored towards
the swing side; :mod:`jaxloco.planner.steering`), carried along its LIPM orbit to the apex
(``lipm.apex_growth_of``), and the step policy (the learned RL-PSP) picks the action there;
the PSP gives the footstep and the switch time (Algorithm 2). The foot placed by step k
starts the frame of step k+1, turned by the commanded heading change ``turns[k]`` (Fig. 11).
The CoM reference is the LIPM's analytic solution about the stance foot (Eq. 35), at a
constant height ``psp.h`` above it (the walking controller sets it to
``GaitParams.com_height``).

**Replanning** (Eq. 33-34). When ``|[x_d - x; 0.5 (xd_d - xd)]|`` (horizontal CoM) stays
above ``replan_threshold`` for longer than ``replan_delay`` during a swing, the step is
planned again from ``x_new = gamma x_d + (1 - gamma) x`` (position and velocity), the CoM
reference restarts there, and the swing foot moves from its current desired position,
velocity and acceleration to the new footstep (no jump; :func:`.swing.retarget_swing`).
A capture step (below) keeps its touch-down time when it is re-planned: only its target
moves. With ``replan_at_touchdown``, a step whose touch-down finds the error above the
threshold is planned from the blend too, and its CoM reference starts there.

Plans that have no solution (``INFEASIBLE`` reasons) fall back to a capture step
(:func:`capture_step`) and are counted in ``GaitState.failed_plans``; footsteps are
clipped to ``step_x_range`` x ``step_y_range`` and step durations to
``[min_step_duration, max_step_duration]``.

**Step timing adaptation.** The PSP times a step by the sagittal orbits. A plan whose
touch-down comes after the lateral DCM has left ``max_lateral_dcm``, or after the CoM has run
``max_com_lead`` ahead of the stance foot, is shortened to land then, on the capture step
(``Reason.STEP_SHORTENED`` in ``last_reason``).

**Touch-down.** The new stance frame takes the landing foot's measured x, y and its
planned height (a late foot is still in the air). Optionally
(``max_touchdown_delay``) the switch waits for the foot to be down.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from jaxloco.dynamics import se3
from jaxloco.locomotion.gait_params import RIGHT, GaitOverrides, GaitParams
from jaxloco.locomotion.step_timing import capture_step, com_lead_time_limit, dcm_time_limit
from jaxloco.locomotion.swing import Motion, SwingSpline, make_swing, quintic, retarget_swing
from jaxloco.planner import lipm
from jaxloco.planner.psp import INFEASIBLE, PSPParams, Reason, plan_apex_components
from jaxloco.planner.steering import local_to_world, world_to_local

START, WALK = 0, 1

Policy = Callable[[jax.Array], jax.Array]


@struct.dataclass
class GaitState:
    phase: jax.Array
    """() int32, ``START`` (double support before the first step) or ``WALK``."""
    step: jax.Array
    """Steps begun so far (the first lift-off begins step 1)."""
    stance: jax.Array
    """Stance foot: 0 left, 1 right (in START: the first stance foot)."""
    step_start: jax.Array
    """() time the current step began (s)."""
    step_duration: jax.Array
    """Planned time from the step's start to its touch-down."""
    stance_weight0: jax.Array
    """Contact weight of the stance foot at the step's start (1 when it already bore load)."""
    stance_pos: jax.Array
    """(3,) stance foot's contact-frame position (world)."""
    heading: jax.Array
    """() heading of the current step (rad, about world z)."""
    lateral_sign: jax.Array
    """() +1 or -1: the world-frame sign of local +y, from the stance foot towards the swing
    side."""
    next_heading: jax.Array
    """() heading the next step turns to (rad)."""
    foot_yaw: jax.Array
    """(2,) yaw targets of the feet (left, right)."""
    body_yaw0: jax.Array
    """() pelvis and torso yaw at the step's start (rad)."""
    body_yaw1: jax.Array
    """Pelvis/torso yaw interpolates from yaw0 to yaw1 over the step."""
    com_t0: jax.Array
    """() time of the CoM reference's initial state (s)."""
    com_pos0: jax.Array
    """(2,) horizontal CoM position of the reference's initial state (m)."""
    com_vel0: jax.Array
    """CoM reference: LIPM about the stance foot from (pos0, vel0) at com_t0 (horizontal)."""
    start_com: jax.Array
    """(3,) CoM at the start of START (the quintic's origin)."""
    com_height: jax.Array
    """Reference CoM height above the stance foot (m)."""
    swing: SwingSpline
    """The swing foot's spline to its target."""
    swing_yaw0: jax.Array
    """() the swing foot's yaw at lift-off (rad)."""
    turns: jax.Array
    """(N,) heading change per step (rad); after the last, straight on."""
    error_time: jax.Array
    """() how long Eq. 33's error has been above the threshold (s): replanning waits
    ``replan_delay``."""
    overrides: GaitOverrides
    """This robot's replanning switch, speed cap and replan numbers."""
    replans: jax.Array
    """() int32, replans so far."""
    failed_plans: jax.Array
    """() int32, plans so far with no PSP solution (a fallback capture step instead)."""
    last_apex: jax.Array
    """(3,) the last plan's apex state ``(y, xd, yd)`` in the stance frame (m, m/s, m/s)."""
    last_action: jax.Array
    """(3,) the last plan's action ``(p_x, xd_apex_next, yd_apex_next)`` (m, m/s, m/s)."""
    last_reason: jax.Array
    """() int32, the last plan's :class:`~jaxloco.planner.psp.Reason` bits."""
    target: jax.Array
    """(3,) footstep the swing foot is heading to (world)."""


@struct.dataclass
class GaitReferences:
    """What the controller needs from the gait this tick."""

    contact: jax.Array
    """(2,) contact weights of (left, right) in [0, 1]."""
    swinging: jax.Array
    """(2,) 1 for a foot whose swing tasks are on."""
    com: Motion
    """The CoM's reference, each (3,) (m, m/s, m/s^2)."""
    swing: Motion
    """The swing foot's contact-frame reference, world, each (3,)."""
    swing_foot: jax.Array
    """() int32, the swing foot: 0 left, 1 right."""
    swing_yaw: Motion
    """The swing foot's yaw (rad), yaw rate and yaw acceleration, scalars."""
    body_yaw: Motion
    """The pelvis' and torso's yaw (rad), rate and acceleration, scalars."""
    com_error: jax.Array
    """() Eq. 33's error norm."""


def _smoothstep(u):
    """``(s, ds/du, d2s/du2)`` of ``3u^2 - 2u^3`` clipped to [0, 1]."""
    inside = (u > 0) & (u < 1)
    u = jnp.clip(u, 0.0, 1.0)
    return (
        3 * u**2 - 2 * u**3,
        jnp.where(inside, 6 * u - 6 * u**2, 0.0),
        jnp.where(inside, 6 - 12 * u, 0.0),
    )


def _lateral_sign(stance):
    """Local +y points from the stance foot to the other: world-left when standing on the
    right foot."""
    return jnp.where(stance == RIGHT, 1.0, -1.0)


def start_liftoff_state(params: GaitParams, psp: PSPParams, stance_pos, heading, stance):
    """World CoM (pos 2, vel 2, acc 2) at the first lift-off (see the module doc)."""
    w = psp.omega
    sign = _lateral_sign(stance)
    rel = local_to_world(
        jnp.stack([0.0 * heading, params.start_lateral + 0.0 * heading]), heading, sign
    )
    vel = local_to_world(
        jnp.stack([params.start_speed + 0.0 * heading, 0.0 * heading]), heading, sign
    )
    return stance_pos[:2] + rel, vel, w**2 * rel


def init_gait(
    params: GaitParams,
    psp: PSPParams,
    com,
    feet_pos,
    heading=0.0,
    turns=None,
    num_turns: int = 1,
    overrides: GaitOverrides | None = None,
) -> GaitState:
    """The gait at rest in double support (phase START), for a CoM at ``com`` (3,) and the
    feet's contact frames at ``feet_pos`` (2, 3) (left, right); ``heading`` is the walking
    direction (rad), ``turns`` the per-step heading changes; ``overrides``: this robot's
    per-robot numbers (default: ``GaitOverrides.of(params)``)."""
    com = jnp.asarray(com)
    dtype = com.dtype
    feet_pos = jnp.asarray(feet_pos, dtype)
    stance = jnp.asarray(params.first_stance, jnp.int32)
    heading = jnp.asarray(heading, dtype)
    turns = jnp.zeros((num_turns,), dtype) if turns is None else jnp.asarray(turns, dtype)
    swing_foot = 1 - stance
    zero, zero3 = jnp.zeros((), dtype), jnp.zeros(3, dtype)
    stance_pos = feet_pos[stance]
    return GaitState(
        phase=jnp.asarray(START, jnp.int32),
        step=jnp.asarray(0, jnp.int32),
        stance=stance,
        step_start=zero,
        step_duration=jnp.asarray(params.start_duration, dtype),
        stance_weight0=jnp.ones((), dtype),
        stance_pos=stance_pos,
        heading=heading,
        lateral_sign=_lateral_sign(stance).astype(dtype),
        next_heading=heading,
        foot_yaw=jnp.stack([heading, heading]),
        body_yaw0=heading,
        body_yaw1=heading,
        com_t0=zero,
        com_pos0=com[:2],
        com_vel0=jnp.zeros(2, dtype),
        start_com=com,
        com_height=jnp.asarray(psp.h, dtype),
        swing=make_swing(
            feet_pos[swing_foot], feet_pos[swing_foot], 0.0, 1.0, feet_pos[swing_foot, 2]
        ),
        swing_yaw0=heading,
        turns=turns,
        error_time=zero,
        overrides=GaitOverrides.of(params, dtype) if overrides is None else overrides,
        replans=jnp.asarray(0, jnp.int32),
        failed_plans=jnp.asarray(0, jnp.int32),
        last_apex=zero3,
        last_action=zero3,
        last_reason=jnp.asarray(0, jnp.int32),
        target=feet_pos[swing_foot],
    )


def com_reference(state: GaitState, params: GaitParams, psp: PSPParams, t) -> Motion:
    """Desired CoM position, velocity and acceleration, each (3,), at time ``t``."""
    w = psp.omega
    z = state.stance_pos[2] + state.com_height
    # START: quintic to the first lift-off state; the height settles with it.
    p1, v1, a1 = start_liftoff_state(params, psp, state.stance_pos, state.heading, state.stance)
    zero2 = jnp.zeros_like(p1)
    qp, qv, qa = quintic(
        state.start_com[:2], zero2, zero2, p1, v1, a1, params.start_duration, t - state.step_start
    )
    zp, zv, za = quintic(
        state.start_com[2], 0.0, 0.0, z, 0.0, 0.0, params.start_duration, t - state.step_start
    )
    # WALK: the LIPM about the stance foot (Eq. 35), per horizontal axis.
    pivot = state.stance_pos[:2]
    lp, lv = lipm.propagate(state.com_pos0, state.com_vel0, pivot, w, t - state.com_t0)
    la = lipm.acceleration(lp, pivot, w)
    walking = state.phase == WALK
    pos = jnp.where(walking, jnp.append(lp, z), jnp.append(qp, zp))
    vel = jnp.where(walking, jnp.append(lv, 0.0), jnp.append(qv, zv))
    acc = jnp.where(walking, jnp.append(la, 0.0), jnp.append(qa, za))
    return Motion(pos, vel, acc)


class StepDecision(NamedTuple):
    """A step planned from the CoM state (:func:`_plan`)."""

    duration: jax.Array
    """() time from now to the touch-down (s)."""
    foot_xy: jax.Array
    """(2,) the footstep, world x, y (m)."""
    apex: jax.Array
    """(3,) the apex state ``(y_apex, xd_apex, yd_apex)`` the plan started from."""
    action: jax.Array
    """(3,) the policy's action ``(p_x, xd_apex_next, yd_apex_next)``, speed capped."""
    reason: jax.Array
    """() int32, :class:`~jaxloco.planner.psp.Reason` bit flags of the plan."""
    failed: jax.Array
    """() bool, the PSP had no solution: the step is a capture step."""


def _plan(
    params: GaitParams,
    psp: PSPParams,
    policy: Policy,
    com_pos,
    com_vel,
    stance_pos,
    heading,
    sign,
    fallback_remaining,
    apex_speed_cap,
) -> StepDecision:
    """Plan the step from a horizontal CoM state in the stance frame. A plan the PSP cannot
    make lands a capture step (:func:`capture_step`) in ``fallback_remaining`` s.
    """
    w = psp.omega
    rel = world_to_local(com_pos - stance_pos[:2], heading, sign)
    vel = world_to_local(com_vel, heading, sign)
    tau, v_apex, growth, apex_ok = lipm.apex_growth_of(rel[0], vel[0], 0.0, w)
    y_apex, yd_apex = lipm.propagate_by_growth(rel[1], vel[1], 0.0, w, growth)
    apex = jnp.stack([y_apex, v_apex, yd_apex])
    action = policy(apex)
    action = action.at[1].min(apex_speed_cap)
    plan = plan_apex_components(y_apex, v_apex, yd_apex, action, psp)
    failed = (~apex_ok) | ((plan.reason & int(INFEASIBLE)) != 0)
    duration = jnp.where(failed, fallback_remaining, tau + plan.t_switch)
    # Step timing adaptation: land before the lateral DCM runs out of reach, and before the
    # CoM runs so far ahead that the stance ankle reaches its limit.
    limit = jnp.minimum(
        dcm_time_limit(params, w, rel, vel), com_lead_time_limit(params, w, rel, vel)
    )
    shortened = duration > limit
    duration = jnp.minimum(duration, limit)
    step = jnp.where(
        failed | shortened,
        capture_step(params, w, rel, vel, duration),
        jnp.stack([plan.p_x, plan.p_y]),
    )
    step = jnp.clip(
        step,
        jnp.asarray([params.step_x_range[0], params.step_y_range[0]], rel.dtype),
        jnp.asarray([params.step_x_range[1], params.step_y_range[1]], rel.dtype),
    )
    foot_xy = stance_pos[:2] + local_to_world(step, heading, sign)
    reason = (
        plan.reason
        | jnp.where(apex_ok, 0, int(Reason.NO_APEX))
        | jnp.where(shortened, int(Reason.STEP_SHORTENED), 0)
    ).astype(jnp.int32)
    return StepDecision(duration, foot_xy, apex, action, reason, failed)


def _start_step(
    state: GaitState,
    params,
    t,
    plan: StepDecision,
    stance,
    stance_pos,
    swing_pos,
    heading,
    weight0,
    com: Motion,
):
    """A new single-support step on ``stance`` from time ``t``, planned by ``plan`` from the
    CoM reference ``com`` at ``t`` (see the module doc)."""
    dtype = stance_pos.dtype
    duration = jnp.clip(plan.duration, params.min_step_duration, params.max_step_duration)
    target = jnp.append(plan.foot_xy, stance_pos[2])
    turn_index = jnp.minimum(state.step, state.turns.shape[0] - 1)
    turn = jnp.where(state.step < state.turns.shape[0], state.turns[turn_index], 0.0)
    next_heading = heading + turn
    swing = make_swing(
        swing_pos,
        target,
        t + params.contact_blend,
        duration - params.contact_blend,
        jnp.maximum(swing_pos[2], target[2]) + params.swing_height,
    )
    swing_foot = 1 - stance
    return state.replace(
        phase=jnp.asarray(WALK, jnp.int32),
        step=state.step + 1,
        stance=stance,
        step_start=t,
        step_duration=duration,
        stance_weight0=jnp.asarray(weight0, dtype),
        stance_pos=stance_pos,
        heading=heading,
        lateral_sign=_lateral_sign(stance).astype(dtype),
        next_heading=next_heading,
        body_yaw0=state.body_yaw1,
        body_yaw1=0.5 * (heading + next_heading),
        com_t0=t,
        com_pos0=com.pos[:2],
        com_vel0=com.vel[:2],
        swing=swing,
        swing_yaw0=state.foot_yaw[swing_foot],
        error_time=jnp.zeros((), dtype),
        failed_plans=state.failed_plans + plan.failed.astype(jnp.int32),
        last_apex=plan.apex,
        last_action=plan.action,
        last_reason=plan.reason,
        target=target,
    )


def _replan_remaining(state: GaitState, params, elapsed):
    """Eq. 34's fallback time: when the re-planned step has no solution, the capture step
    lands in this many seconds."""
    # A capture step already under way keeps its touch-down time (only its target moves):
    # restarting the fallback clock at every replan would postpone the landing as long as
    # the error stays large, which is exactly when the foot must come down.
    in_fallback = (state.last_reason & int(INFEASIBLE)) != 0
    return jnp.where(
        in_fallback,
        jnp.maximum(state.step_duration - elapsed, params.replan_min_remaining),
        jnp.clip(params.fallback_duration - elapsed, params.replan_min_remaining + 0.1, None),
    )


def _apply_replan(state: GaitState, params, t, plan: StepDecision, new_pos, new_vel):
    """Eq. 34: the current step re-planned (``plan``) from the blended CoM state
    ``new_pos``, ``new_vel`` (2,) each."""
    elapsed = t - state.step_start
    remaining = jnp.clip(plan.duration, params.replan_min_remaining, params.max_step_duration)
    target = jnp.append(plan.foot_xy, state.stance_pos[2])
    pos = state.swing.evaluate(t)[0]
    swing = retarget_swing(
        state.swing,
        t,
        target,
        remaining,
        jnp.maximum(pos[2], target[2] + params.swing_height * jnp.clip(remaining / 0.3, 0.0, 1.0)),
    )
    return state.replace(
        step_duration=elapsed + remaining,
        com_t0=t,
        com_pos0=new_pos,
        com_vel0=new_vel,
        swing=swing,
        error_time=jnp.zeros_like(state.error_time),
        replans=state.replans + 1,
        failed_plans=state.failed_plans + plan.failed.astype(jnp.int32),
        last_apex=plan.apex,
        last_action=plan.action,
        last_reason=plan.reason,
        target=target,
    )


def com_error(reference: Motion, com, com_vel):
    """Eq. 33 on the horizontal CoM state, against the CoM reference at the same time
    (:func:`com_reference`)."""
    err = jnp.concatenate([reference.pos[:2] - com[:2], 0.5 * (reference.vel[:2] - com_vel[:2])])
    return jnp.linalg.norm(err)


def advance(
    state: GaitState,
    params: GaitParams,
    psp: PSPParams,
    policy: Policy,
    t,
    com,
    com_vel,
    feet_pos,
    dt,
) -> GaitState:
    """One tick of the state machine at time ``t`` given the measured CoM (3,), its
    velocity (3,) and the feet's contact-frame positions (2, 3)."""
    t = jnp.asarray(t, state.step_start.dtype)
    dtype = state.step_start.dtype
    elapsed = t - state.step_start
    # A touch-down waits (up to max_touchdown_delay) for the landing foot to be down.
    landing = 1 - state.stance
    down = feet_pos[landing, 2] <= state.target[2] + params.touchdown_height
    late = elapsed >= state.step_duration + params.max_touchdown_delay - 1e-9
    due = (elapsed >= state.step_duration - 1e-9) & ((state.phase == START) | down | late)
    first = state.phase == START  # a due step from START is the first lift-off

    # Replanning (Eq. 33-34), only while a foot swings and not when it is about to land (a
    # step begun this tick has not started to swing).
    ref = com_reference(state, params, psp, t)
    err = com_error(ref, com, com_vel)
    swinging = (state.phase == WALK) & (elapsed >= params.contact_blend) & ~due
    over = (
        swinging
        & (err > state.overrides.replan_threshold)
        & (state.step_duration - elapsed > params.replan_min_remaining)
    )
    error_time = jnp.where(over, state.error_time + dt, 0.0)
    state = state.replace(error_time=error_time)
    delay = params.replan_delay
    if params.replan_delay_behind is not None:
        # Behind along the heading: Eq. 33's position and velocity terms, sagittal part.
        ahead = jnp.stack([jnp.cos(state.heading), jnp.sin(state.heading)])
        sagittal = (ref.pos[:2] - com[:2] + 0.5 * (ref.vel[:2] - com_vel[:2])) @ ahead
        delay = jnp.where(sagittal > 0, params.replan_delay_behind, delay)
    replan = over & (error_time > delay) & state.overrides.replan

    # The new step, when one is due: at the first lift-off on the current stance foot; at a
    # touch-down on the landed foot, which stands where it was measured at the height it
    # was planned to land at (a foot that lands late, after a push, is still in the air at
    # the planned touch-down, and its measured height would lift every later footstep and
    # the CoM reference off the floor: docs/architecture.md, measured choices).
    landed_pos = feet_pos[landing].at[2].set(state.target[2])
    stance = jnp.where(first, state.stance, landing)
    stance_pos = jnp.where(first, feet_pos[state.stance], landed_pos)
    swing_pos = jnp.where(first, feet_pos[landing], feet_pos[state.stance])
    heading = jnp.where(first, state.heading, state.next_heading)
    weight0 = jnp.where(first, 1.0, 0.0)
    g = state.overrides.replan_gamma
    new_pos = g * ref.pos[:2] + (1 - g) * com[:2]
    new_vel = g * ref.vel[:2] + (1 - g) * com_vel[:2]
    # A step begun at a touch-down far off the reference starts from the blend too (off:
    # nothing added to the program).
    start_ref = ref
    if params.replan_at_touchdown:
        far = err > state.overrides.replan_threshold
        blend = (state.phase == WALK) & far & state.overrides.replan
        start_ref = ref._replace(
            pos=ref.pos.at[:2].set(jnp.where(blend, new_pos, ref.pos[:2])),
            vel=ref.vel.at[:2].set(jnp.where(blend, new_vel, ref.vel[:2])),
        )

    # One plan per tick at most (a step begins, or the current one is re-planned), so the
    # policy appears once in the program.
    def plan(_):
        return _plan(
            params,
            psp,
            policy,
            jnp.where(due, start_ref.pos[:2], new_pos),
            jnp.where(due, start_ref.vel[:2], new_vel),
            jnp.where(due, stance_pos, state.stance_pos),
            jnp.where(due, heading, state.heading),
            jnp.where(due, _lateral_sign(stance).astype(dtype), state.lateral_sign),
            jnp.where(
                due,
                jnp.asarray(params.fallback_duration, dtype),
                _replan_remaining(state, params, elapsed),
            ),
            state.overrides.apex_speed,
        )

    def no_plan(_):
        zero = jnp.zeros((), dtype)
        return StepDecision(
            zero,
            jnp.zeros(2, dtype),
            jnp.zeros(3, dtype),
            jnp.zeros(3, dtype),
            jnp.zeros((), jnp.int32),
            jnp.zeros((), bool),
        )

    decision = jax.lax.cond(due | replan, plan, no_plan, None)

    def begin(s):
        s = s.replace(
            foot_yaw=jnp.where(first, s.foot_yaw, s.foot_yaw.at[landing].set(s.next_heading))
        )
        return _start_step(
            s, params, t, decision, stance, stance_pos, swing_pos, heading, weight0, start_ref
        )

    def replanned(s):
        return _apply_replan(s, params, t, decision, new_pos, new_vel)

    branch = jnp.where(due, 1, jnp.where(replan, 2, 0))
    return jax.lax.switch(branch, [lambda s: s, begin, replanned], state)


def references(
    state: GaitState, params: GaitParams, psp: PSPParams, t, com, com_vel
) -> GaitReferences:
    """The contact set and the task references at time ``t``."""
    dtype = state.step_start.dtype
    elapsed = t - state.step_start
    walking = state.phase == WALK
    blend = params.contact_blend
    stance_w = jnp.clip(state.stance_weight0 + elapsed / blend, 0.05, 1.0)
    swing_w = jnp.clip(1.0 - elapsed / blend, 0.0, 1.0)
    stance_w = jnp.where(walking, stance_w, 1.0)
    swing_w = jnp.where(walking, swing_w, 1.0)
    swing_foot = 1 - state.stance
    contact = jnp.zeros(2, dtype).at[state.stance].set(stance_w).at[swing_foot].set(swing_w)
    swinging = jnp.zeros(2, dtype).at[swing_foot].set((swing_w <= 0).astype(dtype))

    s, ds, dds = _smoothstep(elapsed / state.step_duration)
    dyaw = state.body_yaw1 - state.body_yaw0
    body_yaw = Motion(
        state.body_yaw0 + dyaw * s,
        dyaw * ds / state.step_duration,
        dyaw * dds / state.step_duration**2,
    )
    swing_t = (t - state.swing.t0) / state.swing.duration
    u, du, ddu = _smoothstep(swing_t)
    fyaw = state.next_heading - state.swing_yaw0
    swing_yaw = Motion(
        state.swing_yaw0 + fyaw * u,
        fyaw * du / state.swing.duration,
        fyaw * ddu / state.swing.duration**2,
    )
    swing_pos, swing_vel, swing_acc = state.swing.evaluate(t)
    waiting = walking & (elapsed > state.step_duration)  # a late foot: press it down
    swing_pos = swing_pos.at[2].add(jnp.where(waiting, -params.late_landing_depth, 0.0))
    com_ref = com_reference(state, params, psp, t)
    return GaitReferences(
        contact=contact,
        swinging=swinging,
        com=com_ref,
        swing=Motion(swing_pos, swing_vel, swing_acc),
        swing_foot=swing_foot,
        swing_yaw=swing_yaw,
        body_yaw=body_yaw,
        com_error=com_error(com_ref, com, com_vel),
    )


def yaw_reference(yaw: Motion) -> Motion:
    """Quaternion (4,), angular velocity and acceleration (3,) of a yaw-only orientation
    from its yaw (rad), rate and acceleration."""
    zero = jnp.zeros_like(yaw.pos)
    return Motion(
        se3.yaw_quat(yaw.pos), jnp.stack([zero, zero, yaw.vel]), jnp.stack([zero, zero, yaw.acc])
    )
