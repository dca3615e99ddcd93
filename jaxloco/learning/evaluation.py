"""Evaluating step policies: the survival basin, and the learned policy and value as functions.

**Survival basin**: the fraction of apex states drawn uniformly from the box of Eq. 1 from
which a deterministic policy walks ``num_steps`` steps without a terminal condition.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxloco.learning import policy as pol
from jaxloco.learning import rbf
from jaxloco.learning.starts import StartStates, uniform_states
from jaxloco.planner import PSPParams, plan_steps


def mean_policy(params: pol.ActorCriticParams, grid: rbf.RBFGrid, psp: PSPParams):
    """The deterministic policy ``state (3,) -> action (3,)``: the mean, clipped to the box."""
    return mean_weights_policy(params.table[..., pol.MEAN], params.bias[pol.MEAN], grid, psp)


def mean_weights_policy(table, bias, grid: rbf.RBFGrid, psp: PSPParams):
    """:func:`mean_policy` from the mean channels alone (``table (*table_shape, 3)``,
    ``bias (3,)``). Each state gathers a window of 3 channels instead of all 7 (the gradient
    scatters one): the faster read-out and gradient (docs/architecture.md, measured choices)."""
    low, high = jnp.asarray(psp.action_low), jnp.asarray(psp.action_high)

    def policy(state):
        mean = rbf.evaluate(table, bias, rbf.local_features(grid, state))
        return pol.mean_action(mean, low.astype(mean.dtype), high.astype(mean.dtype))

    return policy


def over_states(fn, state):
    """``fn`` of one apex state ``(3,) -> (...)`` applied over apex states ``(..., 3)``
    (vmapped over the flattened leading axes)."""
    state = jnp.asarray(state)
    if state.shape[-1:] != (3,):
        raise ValueError(f"apex states must have shape (..., 3); got {state.shape}")
    out = jax.vmap(fn)(state.reshape(-1, 3))
    return out.reshape(*state.shape[:-1], *out.shape[1:])


def value_function(params: pol.ActorCriticParams, grid: rbf.RBFGrid):
    """The learned value ``state (3,) -> v(s)`` (the paper's walking-risk indicator)."""

    def value(state):
        return pol.network_outputs(params, rbf.local_features(grid, state))[0]

    return value


def steps_survived(policy, states, psp: PSPParams, num_steps: int = 50, turns=None):
    """``(n,)`` number of safe steps the policy takes from each apex state (max num_steps).

    ``turns``: optional ``(num_steps,)`` heading changes (rad) applied after each step, as
    in :func:`~jaxloco.planner.plan_steps` (e.g. Fig. 11's schedule from ``turn_schedule``).
    """
    return jax.vmap(
        lambda s: plan_steps(s, policy, psp, num_steps=num_steps, turns=turns).num_safe_steps
    )(states)


def survival_basin(
    policy,
    psp: PSPParams,
    key,
    num_states: int = 4096,
    num_steps: int = 50,
    spec: StartStates = StartStates(),
    turns=None,
):
    """Fraction of uniform box states from which ``policy`` survives ``num_steps`` steps.

    With ``turns`` (``(num_steps,)`` rad) the walk steers by that schedule: the *steering
    basin*. Returns ``(fraction, states (n, 3), steps (n,))``.
    """
    states = uniform_states(key, num_states, spec)
    steps = steps_survived(policy, states, psp, num_steps, turns)
    return jnp.mean(steps == num_steps), states, steps
