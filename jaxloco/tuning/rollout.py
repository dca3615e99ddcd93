"""A differentiable closed-loop rollout in MJX: time-averaged costs, memory O(sqrt(horizon)).

:func:`mean_costs` runs the same closed-loop tick as every MJX rollout
(:func:`jaxloco.sim.mjx_loop.closed_loop_step`: controller, pushes, ``mjx.step``, falls
frozen) and returns the time average of the scalar costs the controller logs. Reverse-mode
gradients flow through it when the physics model has ``opt.iterations == 1`` (MJX's
solver loop is a ``while_loop`` otherwise; :func:`tuning_physics` sets it).

Memory: the ticks are scanned in segments of ``segment`` ticks, each segment under
``jax.checkpoint``. The backward pass keeps one loop state per segment and recomputes a
segment's ticks when it gets there, so memory grows as ``steps / segment + segment`` loop
states instead of ``steps`` full sets of intermediates, at the price of one extra forward
pass (``segment`` near ``sqrt(steps)`` minimises it in principle). On CPU, though, XLA
compiles the reverse pass of long segments far more slowly, so the tuning problems use
``segment=1`` (``docs/tuning.md``). ``segment == steps`` is a single plain scan: what
forward-mode gradients want (they keep nothing for a backward pass).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco

from jaxloco.sim.mjx_loop import LoopState, PhysicsParams, closed_loop_step, physics_model
from jaxloco.sim.push import PushArrays


def tuning_physics(
    model: mujoco.MjModel, ls_iterations: int = 4, torque_limit: float | None = None
) -> mujoco.MjModel:
    """``model`` with the solver settings reverse-mode differentiation needs (one solver
    iteration, eulerdamp off). ``torque_limit``: see :class:`PhysicsParams`; the default
    keeps the model's own effort limits, which the body-shaking tuning and its held-out
    check on MuJoCo C use."""
    params = PhysicsParams(iterations=1, ls_iterations=ls_iterations, torque_limit=torque_limit)
    return physics_model(model, params)


def check_differentiable(model: mujoco.MjModel) -> None:
    if int(model.opt.iterations) != 1:
        raise ValueError(
            "reverse-mode gradients through mjx.step need model.opt.iterations == 1 (MJX's "
            f"solver loop is a while_loop otherwise); got {model.opt.iterations}: build the "
            "physics model with jaxloco.tuning.rollout.tuning_physics"
        )


def depend_on(state, params):
    """``state`` with zero times the sum of ``params``' leaves added to each floating-point
    leaf: the same values, but every carry of a rollout started from it now depends on the
    parameters (and, under ``vmap`` over tangents or samples, is batched) from the first
    tick. JAX's ``scan`` rules find which carries carry tangents (``jvp``), are unknown
    (reverse mode) or batched (``vmap``) by tracing the tick again until the set stops
    growing; from such a start the first pass is the last, so the gradients trace the tick
    once per rule instead of about three times (docs/tuning.md)."""
    zero = 0.0 * sum(jnp.sum(leaf) for leaf in jax.tree.leaves(params))

    def tie(x):
        return x + zero.astype(x.dtype) if jnp.issubdtype(x.dtype, jnp.inexact) else x

    return jax.tree.map(tie, state)


def mean_costs(
    mx,
    controller: Callable,
    state: LoopState,
    steps: int,
    segment: int = 50,
    pushes=None,
    push_body: int = 0,
    fall_height: float = 0.5,
) -> tuple[LoopState, dict]:
    """Run ``steps`` ticks; return the final state and the time mean of every entry of the
    controller's ``log`` (scalars: the per-tick costs).

    ``controller(t, qpos, qvel, cstate, engine=d) -> (torques, cstate, costs)``, ``d`` the
    state's MJX data after its position and velocity stages (see
    :func:`~jaxloco.sim.mjx_loop.closed_loop_step`). ``steps`` must be a
    multiple of ``segment``. Ticks after a fall add the frozen state's costs (the state
    stops changing; see :func:`closed_loop_step`).
    """
    if steps < 1 or segment < 1 or steps % segment:
        raise ValueError(
            f"mean_costs: steps ({steps}) must be a positive multiple of segment ({segment})"
        )
    if pushes is None:
        pushes = PushArrays.none(dtype=state.data.qpos.dtype)

    def tick(s, _):
        s, record = closed_loop_step(mx, controller, s, pushes, push_body, fall_height)
        return s, record.controller

    if segment == steps:
        # One segment: one scan, nothing to checkpoint (forward mode keeps nothing for a
        # backward pass).
        state, logs = jax.lax.scan(tick, state, None, length=steps)
        return state, jax.tree.map(lambda v: jnp.sum(v, axis=0) / steps, logs)

    @jax.checkpoint
    def run_segment(s, _):
        s, logs = jax.lax.scan(tick, s, None, length=segment)
        return s, jax.tree.map(lambda v: jnp.sum(v, axis=0), logs)

    state, sums = jax.lax.scan(run_segment, state, None, length=steps // segment)
    return state, jax.tree.map(lambda v: jnp.sum(v, axis=0) / steps, sums)
