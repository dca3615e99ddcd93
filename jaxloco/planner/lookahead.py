"""A search policy: the best action on a grid over the action box, one step ahead.

No learning involved. It scores every grid action by the step's reward (Eq. 3) plus a
discounted value of the next apex state, rejecting actions whose step is terminal. With no
learned value it uses a quadratic distance to the nominal apex state. It serves as the
baseline the learned RL policy is compared with, and lets the planner steer and recover
before a policy is trained. Cost: one vectorised ``plan_step`` per grid point per step.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxloco.planner.psp import PSPParams, plan_step

ValueFn = Callable[[jax.Array], jax.Array]


def action_grid(params: PSPParams, shape=(9, 9, 11)) -> np.ndarray:
    """``(prod(shape), 3)`` actions on a regular grid spanning the action box (Eq. 2)."""
    if len(shape) != 3 or any(int(n) < 1 for n in shape):
        raise ValueError(f"grid shape must be three counts >= 1; got {shape!r}")
    axes = [
        np.linspace(lo, hi, int(n)) if n > 1 else np.array([(lo + hi) / 2])
        for lo, hi, n in zip(params.action_low, params.action_high, shape, strict=True)
    ]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def nominal_distance_value(params: PSPParams, weights=(30.0, 1.0, 1.0)) -> ValueFn:
    """A hand-set value: minus the weighted squared distance to the nominal apex state."""
    nominal = jnp.asarray(params.nominal_state)
    w = jnp.asarray(weights)

    def value(state):
        d = state - nominal.astype(state.dtype)
        return -jnp.sum(w * d * d, axis=-1)

    return value


def make_lookahead_policy(
    params: PSPParams = PSPParams(),
    grid_shape=(9, 9, 11),
    value_fn: ValueFn | None = None,
    discount: float = 0.9,
):
    """A policy ``apex_state (3,) -> action (3,)`` that searches the action grid.

    Returns the grid action maximising ``reward + discount * value(next_state)`` among
    non-terminal steps; if every step is terminal, the one with the best score anyway.
    """
    grid = jnp.asarray(action_grid(params, grid_shape))
    value_fn = nominal_distance_value(params) if value_fn is None else value_fn

    def policy(state):
        actions = grid.astype(state.dtype)
        plan = plan_step(state[None, :], actions, params)
        score = plan.reward + discount * value_fn(plan.next_state)
        # Terminal steps rank below every safe one but keep their order among themselves.
        score = jnp.where(plan.terminal, score - 1e6, score)
        return actions[jnp.argmax(score)]

    return policy
