"""Closed loop in MJX: physics + the jitted controller as one pure step, scanned and vmapped.

:func:`closed_loop_step` is one control tick and one physics step (pure torque control at
the model's timestep, 1 kHz for Valkyrie): the controller reads ``(time, qpos, qvel)``,
pushes set ``xfrc_applied`` on one body, and ``mjx.step`` integrates. :func:`rollout` scans
it over a horizon and logs every ``log_every``-th tick (:class:`RolloutLog`), so long
horizons do not hold every tick in memory (sweeps fold every tick into an accumulator
instead: :mod:`jaxloco.sweep.outcome`). Batch with
``jax.vmap`` over initial states and pushes (:func:`batched_rollout`).

A robot that falls (pelvis below ``fall_height``, or a non-finite state) is frozen from
that tick on (its state stops changing; shapes stay static) and its fall time recorded.

Physics settings: :func:`physics_model` returns an MJX model with the solver settings
the closed loop uses; the defaults (Newton, 100 iterations, 50 line-search iterations) are
MJX's slowest; :class:`PhysicsParams` defaults to 2 iterations, 4 line-search steps and
eulerdamp off, and clips every actuator at 500 N m as the paper's authors simulated
(``torque_limit="model"``: the model's own effort limits). ``tests/test_locomotion.py`` checks
that MJX and MuJoCo's C engine, both at these settings, give the same walking motion (it
does not compare against the defaults).
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable
from typing import Any, Union

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from jaxloco import validation as v
from jaxloco.dynamics.quiet_mjx import mjx
from jaxloco.sim.push import push_force

MODEL_LIMITS = "model"
"""``PhysicsParams.torque_limit``'s value for the model's own per-joint effort limits."""


@dataclasses.dataclass(frozen=True)
class PhysicsParams:
    """MuJoCo settings of the simulated robot (not the controller's model): solver
    iterations, Euler damping and the actuators' torque limit."""

    iterations: int = 2
    """Constraint-solver iterations of the simulation (MuJoCo's ``opt.iterations``)."""
    ls_iterations: int = 4
    """Its line-search iterations (``opt.ls_iterations``)."""
    eulerdamp: bool = False
    """MuJoCo's implicit joint damping in the Euler integrator; off (``mjDSBL_EULERDAMP`` set) as
    the paper's authors simulated."""
    torque_limit: Union[float, str, None] = 500.0  # noqa: UP007 (OmegaConf needs typing.Union)
    """Every actuator clips at +-this (N m). The default is what the paper's authors
    simulated (their code bounded every joint at 500 N m; the paper names no limit).
    ``"model"`` (or None): the model's own per-joint effort limits, for Valkyrie its
    published ones (26 N m at the neck, 150 at the torso pitch, 190 at the shoulders, up to
    350 in the legs): a stricter robot than the paper's."""

    def __post_init__(self):
        limit = self.torque_limit
        if limit is None:  # one spelling, so equal settings hash alike
            object.__setattr__(self, "torque_limit", MODEL_LIMITS)
        elif isinstance(limit, int) and not isinstance(limit, bool):
            object.__setattr__(self, "torque_limit", float(limit))
        v.check_fields(
            self,
            [
                v.integer(self, "iterations", 1),
                v.integer(self, "ls_iterations", 1),
                (
                    "torque_limit",
                    self.torque_limit in (None, MODEL_LIMITS)
                    or (
                        isinstance(self.torque_limit, (int, float))
                        and not isinstance(self.torque_limit, bool)
                        and self.torque_limit > 0
                    ),
                    f"> 0 N m, or {MODEL_LIMITS!r}: the model's own effort limits",
                ),
            ],
        )


def physics_model(model: mujoco.MjModel, params: PhysicsParams | None = None) -> mujoco.MjModel:
    """A copy of ``model`` with the solver settings of ``params`` (None: MuJoCo's own)."""
    model = copy.deepcopy(model)
    if params is not None:
        model.opt.iterations = params.iterations
        model.opt.ls_iterations = params.ls_iterations
        if params.eulerdamp:
            model.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
        else:
            model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
        if params.torque_limit not in (None, MODEL_LIMITS):
            limit = float(params.torque_limit) / model.actuator_gear[:, 0]
            model.actuator_ctrlrange[:] = np.stack([-limit, limit], axis=1)
            model.actuator_ctrllimited[:] = 1
    return model


@struct.dataclass
class LoopState:
    """The closed loop's state between ticks (add leading axes when batched)."""

    data: mjx.Data
    """The simulated robot's MJX data."""
    controller: Any
    """The controller's own state (e.g. a
    :class:`~jaxloco.locomotion.walking.WalkingState`)."""
    fell: jax.Array
    """() bool, the robot has fallen (its state is frozen from then on)."""
    fall_time: jax.Array
    """() time of the fall (s); inf while standing."""


@struct.dataclass
class LoopTick:
    """What one closed-loop tick records."""

    controller: Any
    """The controller's log of the tick (e.g. a
    :class:`~jaxloco.locomotion.walking_log.WalkingLog`)."""
    force: jax.Array
    """(3,) the push force applied this tick (N, world frame)."""


@struct.dataclass
class RolloutLog:
    """:func:`rollout`'s log: one entry per ``log_every`` ticks (leading axis
    ``steps // log_every``, plus any batch axes in front)."""

    last: LoopTick
    """The interval's last tick."""
    time: jax.Array
    """() simulation time at the interval's end (s)."""
    qpos: jax.Array
    """(nq,) joint positions at the interval's end."""
    fell: jax.Array
    """() bool, fallen by the interval's end."""


def init_loop_state(mx: mjx.Model, qpos, controller_state) -> LoopState:
    """The loop state of a robot at rest at ``qpos``, by ``mjx.forward`` (traced: inside a
    program it is part of that program; :func:`loop_state_from_c` builds it without)."""
    d = mjx.make_data(mx).replace(qpos=jnp.asarray(qpos))
    d = mjx.forward(mx, d)
    dtype = d.qpos.dtype
    return LoopState(d, controller_state, jnp.array(False), jnp.asarray(jnp.inf, dtype))


def mjx_data_from_c(mx: mjx.Model, model: mujoco.MjModel, data: mujoco.MjData) -> mjx.Data:
    """MuJoCo C's ``data`` (after ``mj_forward``) as MJX data with the dtypes ``mjx.step``
    returns, so it can start a ``lax.scan`` of steps (``put_data`` gives some integer
    fields, contact ids, another width under float64)."""
    types = jax.eval_shape(lambda: mjx.make_data(mx))  # step's own types; tracing is free
    return jax.tree.map(lambda x, t: jnp.asarray(x, t.dtype), mjx.put_data(model, data), types)


def loop_state_from_c(
    mx: mjx.Model, model: mujoco.MjModel, data: mujoco.MjData, controller_state
) -> LoopState:
    """The loop state of MuJoCo C's ``data`` (after ``mj_forward``), not fallen: no
    ``mjx.forward`` program to trace or compile."""
    d = mjx_data_from_c(mx, model, data)
    return LoopState(d, controller_state, jnp.array(False), jnp.asarray(jnp.inf, d.qpos.dtype))


def step_first_half(mx: mjx.Model, d: mjx.Data) -> mjx.Data:
    """``mjx.step``'s position and velocity stages (MuJoCo's ``mj_step1``): everything
    that depends on the state alone, before the controls are known."""
    d = mjx.fwd_position(mx, d)
    d = mjx.sensor_pos(mx, d)
    d = mjx.fwd_velocity(mx, d)
    return mjx.sensor_vel(mx, d)


def step_second_half(mx: mjx.Model, d: mjx.Data) -> mjx.Data:
    """The rest of ``mjx.step`` after :func:`step_first_half` and the controls (MuJoCo's
    ``mj_step2``): actuation, acceleration, constraints, integration. The two halves are
    ``mjx.step``'s own stages in its order (tested against it)."""
    d = mjx.fwd_actuation(mx, d)
    d = mjx.fwd_acceleration(mx, d)
    if d._impl.efc_J.size == 0:
        d = d.replace(qacc=d.qacc_smooth)
    else:
        d = mjx.solve(mx, d)
        d = mjx.sensor_acc(mx, d)
    integrator = mx.opt.integrator
    if integrator == mjx.IntegratorType.EULER:
        return mjx.euler(mx, d)
    if integrator == mjx.IntegratorType.RK4:
        return mjx.rungekutta4(mx, d)
    if integrator == mjx.IntegratorType.IMPLICITFAST:
        return mjx.implicit(mx, d)
    raise NotImplementedError(f"MJX has no integrator {integrator}")


def closed_loop_step(
    mx: mjx.Model,
    controller: Callable,
    state: LoopState,
    pushes,
    push_body: int,
    fall_height: float = 0.7,
):
    """One tick: ``controller(t, qpos, qvel, cstate, engine=d) -> (torques, cstate, log)``,
    the :class:`~jaxloco.sim.push.PushArrays` ``pushes`` (world frame, any shape) on
    ``push_body``, then ``mjx.step``, split in its two halves: the controller gets ``d``,
    the state's ``mjx.Data`` after :func:`step_first_half` (the engine's own kinematics,
    inertias and bias forces, which a WBLC snapshot reads instead of computing them a
    second time). Returns ``(state, LoopTick)``."""
    d = step_first_half(mx, state.data)
    torques, cstate, log = controller(d.time, d.qpos, d.qvel, state.controller, engine=d)
    force = jnp.sum(push_force(pushes, d.time).reshape(-1, 3), axis=0)
    xfrc = jnp.zeros_like(d.xfrc_applied).at[push_body, :3].set(force.astype(d.qpos.dtype))
    new = step_second_half(mx, d.replace(ctrl=torques.astype(d.qpos.dtype), xfrc_applied=xfrc))
    finite = jnp.all(jnp.isfinite(new.qpos)) & jnp.all(jnp.isfinite(new.qvel))
    fell_now = (~finite) | (new.qpos[2] < fall_height)
    fell = state.fell | fell_now
    # A fallen robot is frozen: nothing non-finite or meaningless propagates.
    keep_old = state.fell | ~finite
    data = jax.tree.map(lambda a, b: jnp.where(keep_old, a, b), d, new)
    cstate = jax.tree.map(lambda a, b: jnp.where(state.fell, a, b), state.controller, cstate)
    fall_time = jnp.where(fell & ~state.fell, d.time, state.fall_time)
    return LoopState(data, cstate, fell, fall_time), LoopTick(log, force)


def rollout(
    mx: mjx.Model,
    controller: Callable,
    state: LoopState,
    pushes,
    push_body: int,
    steps: int,
    log_every: int = 10,
    fall_height: float = 0.7,
):
    """``steps`` closed-loop ticks (a multiple of ``log_every``). Returns the final state
    and a :class:`RolloutLog`, one entry per ``log_every`` ticks."""
    if steps < 1 or log_every < 1 or steps % log_every:
        raise ValueError(
            f"rollout: steps ({steps}) must be a positive multiple of log_every ({log_every})"
        )

    def tick(s, _):
        return closed_loop_step(mx, controller, s, pushes, push_body, fall_height)

    def chunk(s, _):
        # Only the interval's last tick is returned: long horizons stay small in memory.
        s, ticks = jax.lax.scan(tick, s, None, length=log_every)
        last = jax.tree.map(lambda x: x[-1], ticks)
        return s, RolloutLog(last, s.data.time, s.data.qpos, s.fell)

    return jax.lax.scan(chunk, state, None, length=steps // log_every)


def batched_rollout(mx, controller, states, pushes, push_body, steps, log_every=10, **kw):
    """:func:`rollout` vmapped over a leading batch axis of ``states`` and ``pushes``."""
    return jax.vmap(lambda s, p: rollout(mx, controller, s, p, push_body, steps, log_every, **kw))(
        states, pushes
    )
