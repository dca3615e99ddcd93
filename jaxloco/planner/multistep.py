"""Multi-step planning: ``lax.scan`` of the PSP over N steps, with steering.

Each step starts from the CoM state relative to its stance foot, in that step's local frame
(see :mod:`jaxloco.planner.steering`). For straight walking this is the apex state; after a
heading change the projected state is generally not at an apex, so it is first carried along
its own orbit to the apex of the new frame (``lipm.apex_of``; possibly backwards in time),
which is what the policy sees. The result holds the footsteps in the world frame, absolute
switch and apex times, the per-step plans and an ``alive`` mask; steps after the first
terminal one are still computed (static shapes) but masked out.

A single trajectory per call: ``jax.vmap`` over start states (and actions) for batches.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

from jaxloco.planner import lipm
from jaxloco.planner.psp import PSPParams, Reason, StepPlan, plan_apex_components
from jaxloco.planner.steering import local_to_world, reproject_com_state, turn_local_frame

Policy = Callable[[jax.Array], jax.Array]


@struct.dataclass
class FootstepPlan:
    """N planned steps. Index k is the step taken from stance foot k to stance foot k+1."""

    steps: StepPlan
    """Per-step plans (leading axis N), each from its apex state."""
    start_states: jax.Array
    """(N, 4) CoM state (x, xd, y, yd) at each step's start, rel. to its stance foot."""
    apex_states: jax.Array
    """(N, 3) apex state each action was chosen from (the policy's input)."""
    actions: jax.Array
    """(N, 3) actions (p_x, xd_apex_next, yd_apex_next)."""
    apex_shift: jax.Array
    """(N,) time from a step's start to its apex (0 when walking straight)."""
    footsteps: jax.Array
    """(N + 1, 2) world positions of the stance feet; [0] is the initial one."""
    headings: jax.Array
    """(N + 1,) heading of each stance frame (rad)."""
    lateral_signs: jax.Array
    """(N + 1,) +1 where the local y axis is world-left of the heading."""
    t_start: jax.Array
    """(N,) absolute time at which each step starts."""
    t_switch: jax.Array
    """(N,) absolute switch (touch-down) times."""
    t_apex: jax.Array
    """(N,) absolute times of the apex over the newly placed foot."""
    reason: jax.Array
    """(N,) int32 :class:`~jaxloco.planner.psp.Reason` bits of each step."""
    alive: jax.Array
    """(N,) True where this step and all earlier ones are safe."""

    @property
    def num_safe_steps(self) -> jax.Array:
        return jnp.sum(self.alive, axis=-1)


def plan_steps(
    start,
    policy: Policy | jax.Array,
    params: PSPParams = PSPParams(),
    num_steps: int | None = None,
    turns=None,
    *,
    foot=(0.0, 0.0),
    heading=0.0,
    lateral_sign=1.0,
    unroll: int | bool = 1,
) -> FootstepPlan:
    """Plan N steps with a policy or an action sequence.

    Args:
      start: apex state ``(y, xd, yd)`` or general CoM state ``(x, xd, y, yd)`` relative to
        the initial stance foot, in its local frame.
      policy: a function ``apex_state (3,) -> action (3,)``, or an ``(N, 3)`` array of actions.
      params: :class:`PSPParams`.
      num_steps: N; required with a policy function, inferred from an action array.
      turns: optional ``(N,)`` heading changes (rad, positive = left): turn k rotates the
        frame of the foot placed by step k. See :func:`steering.turn_schedule`.
      foot, heading, lateral_sign: world pose of the initial stance frame.
      unroll: passed to ``lax.scan`` (``True`` unrolls fully: fastest for short horizons).
    """
    start = jnp.asarray(start)
    if start.shape not in ((3,), (4,)):
        raise ValueError(
            f"start must be an apex state (3,) or a CoM state (4,); got shape {start.shape}"
            " (use jax.vmap for batches)"
        )
    if start.shape == (3,):
        start = jnp.stack([jnp.zeros_like(start[0]), start[1], start[0], start[2]])
    dtype = start.dtype

    if callable(policy):
        if num_steps is None:
            raise ValueError("num_steps is required when policy is a function")
        actions = jnp.zeros((num_steps, 3), dtype)
    else:
        actions = jnp.asarray(policy, dtype)
        if actions.ndim != 2 or actions.shape[-1] != 3:
            raise ValueError(f"actions must have shape (N, 3); got {actions.shape}")
        if num_steps is not None and num_steps != actions.shape[0]:
            raise ValueError(f"num_steps={num_steps} but {actions.shape[0]} actions were given")
        num_steps = actions.shape[0]
    if num_steps < 1:
        raise ValueError(f"num_steps must be >= 1; got {num_steps}")
    turns = jnp.zeros((num_steps,), dtype) if turns is None else jnp.asarray(turns, dtype)
    if turns.shape != (num_steps,):
        raise ValueError(f"turns must have shape ({num_steps},); got {turns.shape}")

    w = params.omega
    # Headings and lateral signs of every stance frame are known before the scan: do the
    # trigonometry here, vectorised, and keep the loop body free of it.
    psi0 = jnp.asarray(heading, dtype)
    sigma0 = jnp.asarray(lateral_sign, dtype)
    headings = psi0 + jnp.concatenate([jnp.zeros((1,), dtype), jnp.cumsum(turns)])
    signs = sigma0 * jnp.where(jnp.arange(num_steps + 1) % 2 == 0, 1.0, -1.0).astype(dtype)
    xs = (
        jnp.cos(headings[:-1]),
        jnp.sin(headings[:-1]),
        signs[:-1],
        jnp.cos(turns),
        jnp.sin(turns),
        actions,
    )

    def body(carry, xs):
        com, foot_k, t0, alive = carry
        cos_psi, sin_psi, sigma, cos_turn, sin_turn, given_action = xs
        # The apex of this frame (a re-projected state is generally not at one).
        tau, v_apex, growth, apex_ok = lipm.apex_growth_of(com[0], com[1], 0.0, w)
        y_apex, yd_apex = lipm.propagate_by_growth(com[2], com[3], 0.0, w, growth)
        apex = jnp.stack([y_apex, v_apex, yd_apex])
        action = policy(apex) if callable(policy) else given_action
        # The component-wise core: no stack-then-slice of the apex state in the loop.
        plan = plan_apex_components(y_apex, v_apex, yd_apex, jnp.asarray(action, dtype), params)

        t_switch_rel = tau + plan.t_switch
        # Only the re-projection (tau < 0) can put an otherwise safe switch in the past.
        in_past = apex_ok & (t_switch_rel <= 0.0) & (plan.t_switch > params.t_switch_min)
        reason = (
            plan.reason
            | jnp.where(apex_ok, 0, Reason.NO_APEX.value).astype(jnp.int32)
            | jnp.where(in_past, Reason.SWITCH_IN_PAST.value, 0).astype(jnp.int32)
        )
        alive_out = alive & (reason == 0)

        step = jnp.stack([plan.p_x, sigma * plan.p_y])
        new_foot = foot_k + jnp.stack(
            [cos_psi * step[0] - sin_psi * step[1], sin_psi * step[0] + cos_psi * step[1]]
        )
        t_sw_abs = t0 + t_switch_rel
        t_ap_abs = t_sw_abs + plan.t_apex
        # The next apex, in the new foot's mirrored frame, then turned to the new heading.
        ns = plan.next_state
        next_local = jnp.stack([jnp.zeros_like(ns[0]), ns[1], ns[0], ns[2]])
        next_com = turn_local_frame(next_local, -sigma, cos_turn, sin_turn)

        out = dict(
            plan=plan,
            start=com,
            apex=apex,
            action=jnp.asarray(action, dtype),
            tau=tau,
            foot=new_foot,
            t0=t0,
            t_sw=t_sw_abs,
            t_ap=t_ap_abs,
            reason=reason,
            alive=alive_out,
        )
        return (next_com, new_foot, t_ap_abs, alive_out), out

    foot0 = jnp.asarray(foot, dtype)
    carry0 = (start, foot0, jnp.zeros((), dtype), jnp.array(True))
    _, out = jax.lax.scan(body, carry0, xs, unroll=unroll)

    steps = out["plan"]
    steps = steps.replace(reason=out["reason"], terminal=out["reason"] != 0)
    return FootstepPlan(
        steps=steps,
        start_states=out["start"],
        apex_states=out["apex"],
        actions=out["action"],
        apex_shift=out["tau"],
        footsteps=jnp.concatenate([foot0[None], out["foot"]], axis=0),
        headings=headings,
        lateral_signs=signs,
        t_start=out["t0"],
        t_switch=out["t_sw"],
        t_apex=out["t_ap"],
        reason=out["reason"],
        alive=out["alive"],
    )


@struct.dataclass
class ComTrajectory:
    """The CoM path of a :class:`FootstepPlan`, sampled in time (for plots).

    Each step k has two phases of S samples: on stance foot k from the step's start to the
    switch, then on stance foot k+1 from the switch to the next apex. Shapes (N, 2S, ...).
    """

    t: jax.Array
    """Time of each sample from the plan's start (s)."""
    position: jax.Array
    """World CoM position (x, y)."""
    velocity: jax.Array
    """World CoM velocity (xd, yd)."""
    local: jax.Array
    """(x, xd, y, yd) relative to the current stance foot, in its (mirrored) local frame."""
    stance: jax.Array
    """Index of the stance foot (k or k + 1)."""
    alive: jax.Array
    """True while the plan's steps so far are safe."""


def sample_com_trajectory(
    plan: FootstepPlan, params: PSPParams = PSPParams(), samples_per_phase: int = 32
) -> ComTrajectory:
    """Sample the analytic CoM motion of a plan; dead steps are masked by ``alive``."""
    if samples_per_phase < 2:
        raise ValueError(f"samples_per_phase must be >= 2; got {samples_per_phase}")
    w = params.omega
    s = plan.steps
    u = jnp.linspace(0.0, 1.0, samples_per_phase, dtype=plan.t_start.dtype)
    psi_k, sig_k = plan.headings[:-1, None], plan.lateral_signs[:-1, None]
    psi_n, sig_n = plan.headings[1:, None], plan.lateral_signs[1:, None]

    def world(foot, rel_pos, rel_vel):
        return (
            foot[:, None, :] + local_to_world(rel_pos, psi_k, sig_k),
            local_to_world(rel_vel, psi_k, sig_k),
        )

    # Phase 1: on stance foot k, from the step start to the switch.
    d1 = (plan.t_switch - plan.t_start)[:, None] * u
    x0 = plan.start_states
    x1, xd1 = lipm.propagate(x0[:, 0:1], x0[:, 1:2], 0.0, w, d1)
    y1, yd1 = lipm.propagate(x0[:, 2:3], x0[:, 3:4], 0.0, w, d1)
    pos1, vel1 = world(plan.footsteps[:-1], jnp.stack([x1, y1], -1), jnp.stack([xd1, yd1], -1))
    local1 = jnp.stack([x1, xd1, y1, yd1], -1)

    # Phase 2: on stance foot k+1, from the switch to the next apex (still in frame k axes).
    d2 = s.t_apex[:, None] * u
    px, py = s.p_x[:, None], s.p_y[:, None]
    x2, xd2 = lipm.propagate(s.x_switch[:, None] - px, s.xd_switch[:, None], 0.0, w, d2)
    y2, yd2 = lipm.propagate(s.y_switch[:, None] - py, s.yd_switch[:, None], 0.0, w, d2)
    pos2, vel2 = world(plan.footsteps[1:], jnp.stack([x2, y2], -1), jnp.stack([xd2, yd2], -1))
    local2 = reproject_com_state(jnp.stack([x2, xd2, y2, yd2], -1), psi_k, sig_k, psi_n, sig_n)

    steps = jnp.arange(plan.t_start.shape[0])[:, None]
    ones = jnp.ones_like(u, dtype=jnp.int32)
    return ComTrajectory(
        t=jnp.concatenate([plan.t_start[:, None] + d1, plan.t_switch[:, None] + d2], axis=1),
        position=jnp.concatenate([pos1, pos2], axis=1),
        velocity=jnp.concatenate([vel1, vel2], axis=1),
        local=jnp.concatenate([local1, local2], axis=1),
        stance=jnp.concatenate([steps * ones, (steps + 1) * ones], axis=1),
        alive=jnp.repeat(plan.alive[:, None], 2 * samples_per_phase, axis=1),
    )
