"""A gradient-based step planner on the reduced model: actions optimised through ``plan_step``.

The learned RL-PSP policy maps an apex state to an action in one network evaluation. This
planner instead *optimises* the action at every apex, by gradient ascent through the
analytic planner (:func:`jaxloco.planner.plan_step` is differentiable), on a smooth
``horizon``-step objective (1 or 2 steps):

    sum_k discount^k [ r_k  -  barrier_k ]  -  discount^K value_weight |s_K - s_nominal|^2_W

- ``r_k``: the smooth part of Eq. 3 (the reward without its terminal switch);
- ``barrier_k``: softplus penalties on the safety margins of Eq. 4 and the stride bounds
  (``t_switch``, ``t_apex`` above their minima, ``p_y`` and the stride inside their ranges),
  zero well inside the safe set and growing linearly outside it. Where the planner has no
  solution at all (the placeholders are flagged invalid) a constant penalty applies;
- the last term is the nominal-distance value of :mod:`jaxloco.planner.lookahead`.

Non-convex: the optimiser starts from ``num_starts`` points of a coarse grid over the
action box, runs Adam (optax) with the actions clipped to the box after every step, all
starts vmapped, and returns the first-step action of the start whose final objective is
best among those whose first step is safe (the best overall if none is).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxloco import validation as v
from jaxloco.planner.lookahead import action_grid
from jaxloco.planner.psp import PSPParams, plan_step, safety_margins, smooth_reward


@dataclasses.dataclass(frozen=True)
class GradientPlannerParams:
    horizon: int = 2
    """Steps optimised jointly (1 or 2); only the first is taken."""
    iterations: int = 40
    """Adam iterations per starting action."""
    learning_rate: float = 0.02
    """Adam's step size (action units)."""
    start_grid: tuple[int, int, int] = (3, 3, 3)
    """Starting actions: a grid of this shape over the action box (one Adam run each)."""
    margin: float = 0.02
    """Safety margin inside Eq. 4's bounds (s for the times, m for p_y and the stride)."""
    barrier_weight: float = 50.0
    """Weight of the softplus barrier on the safety margins."""
    barrier_sharpness: float = 100.0
    """Softplus sharpness (1/units of the margin)."""
    infeasible_penalty: float = 10.0
    """Penalty of a step whose equations have no solution."""
    discount: float = 0.9
    """Discount of the second step and the terminal value."""
    value_weight: float = 1.0
    """Weight of the terminal value: the last apex state's distance from the nominal."""
    value_weights: tuple[float, float, float] = (30.0, 1.0, 1.0)
    """Per-axis weights ``W`` of that distance (y, xd, yd)."""

    def __post_init__(self):
        v.check_fields(
            self,
            [
                v.one_of(self, "horizon", (1, 2)),
                v.integer(self, "iterations", 1),
                ("start_grid", all(int(n) >= 1 for n in self.start_grid), "ints >= 1"),
                *v.positive(self, "learning_rate", "barrier_weight", "barrier_sharpness"),
                *v.non_negative(self, "margin", "infeasible_penalty"),
                *v.unit_interval(self, "discount"),
            ],
        )

    @property
    def num_starts(self) -> int:
        return int(np.prod(self.start_grid))


def step_objective(state, action, psp: PSPParams, gp: GradientPlannerParams):
    """Smooth score of one step (higher is better) and its plan."""
    plan = plan_step(state, action, psp)
    reward = smooth_reward(plan, action, psp)
    m, k = gp.margin, gp.barrier_sharpness
    # Penalise every margin below gp.margin.
    barrier = jnp.sum(jax.nn.softplus(k * (m - safety_margins(plan, psp))) / k, axis=-1)
    feasible = plan.valid.next_state
    score = reward - gp.barrier_weight * barrier - jnp.where(feasible, 0.0, gp.infeasible_penalty)
    return score, plan


def sequence_objective(state, actions, psp: PSPParams, gp: GradientPlannerParams):
    """Objective of an action sequence ``(horizon, 3)`` from apex ``state``."""
    nominal = jnp.asarray(psp.nominal_state, state.dtype)
    w = jnp.asarray(gp.value_weights, state.dtype)
    total, s, scale = 0.0, state, 1.0
    for k in range(gp.horizon):
        score, plan = step_objective(s, actions[k], psp, gp)
        total = total + scale * score
        s, scale = plan.next_state, scale * gp.discount
    return total - scale * gp.value_weight * jnp.sum(w * (s - nominal) ** 2)


def make_gradient_policy(
    psp: PSPParams = PSPParams(), gp: GradientPlannerParams = GradientPlannerParams()
):
    """A policy ``apex_state (3,) -> action (3,)`` that optimises the action by gradient."""
    low, high = np.asarray(psp.action_low), np.asarray(psp.action_high)
    starts = action_grid(psp, gp.start_grid)
    opt = optax.adam(gp.learning_rate)
    # Optimise in box-normalised units so one learning rate fits every action component.
    span = high - low

    def policy(state):
        dtype = state.dtype
        lo, sp = jnp.asarray(low, dtype), jnp.asarray(span, dtype)
        to_action = lambda u: lo + sp * u  # noqa: E731
        u0 = (jnp.asarray(starts, dtype) - lo) / sp
        u0 = jnp.broadcast_to(u0[:, None, :], (gp.num_starts, gp.horizon, 3))

        def objective(u):
            return sequence_objective(state, to_action(u), psp, gp)

        grad = jax.grad(objective)

        def run(u):
            def body(carry, _):
                u, opt_state = carry
                updates, opt_state = opt.update(-grad(u), opt_state, u)
                return (jnp.clip(optax.apply_updates(u, updates), 0.0, 1.0), opt_state), None

            (u, _), _ = jax.lax.scan(body, (u, opt.init(u)), None, length=gp.iterations)
            return u

        u = jax.vmap(run)(u0)
        scores = jax.vmap(objective)(u)
        first = to_action(u[:, 0])
        safe = ~plan_step(state[None, :], first, psp).terminal
        best = jnp.argmax(jnp.where(safe, scores, scores - 1e6))
        return first[best]

    return policy
