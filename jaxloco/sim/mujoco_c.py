"""Closed loop on MuJoCo's C engine for one robot: ``mj_step`` plus a jitted controller.

The reference backend (and the debugging one): the controller is the same pure function
that MJX rollouts vmap, called once per physics step from Python. Pure torque control; the
control rate is the model's timestep (1 kHz for Valkyrie).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Generic, TypeVar

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from tqdm.auto import tqdm

from jaxloco.dynamics.engine_terms import ENGINE_FIELDS, EngineTerms, engine_terms
from jaxloco.runtime import single_thread_compiler_options
from jaxloco.sim.packing import HostGather, TreeLayout

Log = TypeVar("Log")
"""The type of a controller's per-tick log (e.g. a
:class:`~jaxloco.locomotion.walking_log.WalkingLog`)."""


@dataclasses.dataclass
class ClosedLoopLog(Generic[Log]):
    """A closed-loop run on MuJoCo C, every physics step recorded (``T`` steps)."""

    time: np.ndarray
    """(T,) simulation time at each step, before it (s)."""
    qpos: np.ndarray
    """(T, nq) joint positions before each step."""
    qvel: np.ndarray
    """(T, nv) joint velocities before each step."""
    ctrl: np.ndarray
    """(T, nu) the controls applied."""
    outputs: Log | None
    """The controller's per-tick log with every leaf stacked over time (a leading axis of
    ``T``; numpy); None when no step ran."""
    fell: bool
    """True when the run stopped early because ``stop(data)`` said so."""


def run_closed_loop(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    controller: Callable,
    carry,
    steps: int,
    stop: Callable[[mujoco.MjData], bool] | None = None,
    progress: bool | str = False,
    perturb: Callable[[mujoco.MjData], None] | None = None,
    done: Callable[[Log], bool] | None = None,
    on_step: Callable[[mujoco.MjData], None] | None = None,
    engine: bool = False,
    pure: bool = True,
) -> tuple[ClosedLoopLog[Log], object]:
    """Run ``steps`` physics steps with ``ctrl = controller(t, qpos, qvel, carry)``.

    ``controller`` returns ``(torques, carry, log)``; ``log`` is a pytree of arrays (e.g. a
    :class:`~jaxloco.locomotion.walking_log.WalkingLog`) recorded every step. ``stop(data)``
    ends the run early (a fall).
    ``perturb(data)`` runs before every physics step (e.g. sets ``xfrc_applied`` for pushes);
    ``done(log)`` ends the run (not as a fall) when the controller's log says so.
    ``on_step(data)`` runs after every physics step (e.g. a :mod:`.viewer` redraw).
    ``engine``: each step is ``mj_step1``, the controller, ``mj_step2`` (the same physics
    as ``mj_step``), and the controller is called as ``controller(t, qpos, qvel, carry,
    engine=terms)`` with what ``mj_step1`` computed for the state
    (:class:`~jaxloco.dynamics.engine_terms.EngineTerms`), so it need not compute it again.
    ``pure``: ``controller`` is a JAX function (jitted or not) with no side effects, run as
    a :class:`PackedController` (pass one to reuse its compiled tick across runs).
    ``pure=False`` calls any Python function as it is, with numpy arrays.
    Returns the log and the final carry.
    """
    if engine and model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4:
        raise ValueError("run_closed_loop: engine=True needs mj_step1/mj_step2, which RK4 lacks")
    if steps < 0:
        raise ValueError(f"run_closed_loop: steps must be >= 0; got {steps}")
    if isinstance(controller, PackedController):
        tick = controller.bind(data, carry, engine)
    elif pure:
        tick = PackedController(controller).bind(data, carry, engine)
    else:
        tick = None
    times = np.zeros(steps)
    qpos, qvel = np.zeros((steps, model.nq)), np.zeros((steps, model.nv))
    ctrl = np.zeros((steps, model.nu))
    logs = []
    fell = False
    ran = 0
    bar = tqdm(
        range(steps), desc=progress if isinstance(progress, str) else "sim", disable=not progress
    )
    for k in bar:
        if engine:
            mujoco.mj_step1(model, data)
        if tick is not None:
            torques, log = tick(data.time)
        elif engine:
            terms = engine_terms(data)
            torques, carry, log = controller(data.time, terms.qpos, terms.qvel, carry, engine=terms)
        else:
            torques, carry, log = controller(data.time, data.qpos.copy(), data.qvel.copy(), carry)
        data.ctrl[:] = np.asarray(torques)
        times[k], qpos[k], qvel[k], ctrl[k] = data.time, data.qpos, data.qvel, data.ctrl
        ran = k + 1
        logs.append(log)
        if perturb is not None:
            perturb(data)
        if engine:
            mujoco.mj_step2(model, data)
        else:
            mujoco.mj_step(model, data)
        if on_step is not None:
            on_step(data)
        if not np.all(np.isfinite(data.qpos)) or (stop is not None and stop(data)):
            fell = True
            break
        if done is not None and done(tick.log(log) if tick is not None else log):
            break
    if tick is not None:
        outputs, carry = tick.stacked(logs), tick.carry()
    else:
        outputs = (
            jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *logs) if logs else None
        )
    return (
        ClosedLoopLog(times[:ran], qpos[:ran], qvel[:ran], ctrl[:ran], outputs, fell),
        carry,
    )


class PackedController:
    """A pure controller jitted over packed arrays, built once and reused across runs.

    ``controller(t, qpos, qvel, carry[, engine=terms]) -> (torques, carry, log)`` is a JAX
    function (jitted or not) without side effects. Each tick passes it MuJoCo's state
    gathered into one host buffer, and its carry and log as one array per dtype
    (:mod:`.packing`): a handful of arrays a tick instead of every leaf. The compiled tick
    is kept per layout (carry, log, state fields), so the runs of one controller from
    carries of one layout share one trace and one compile; a controller made anew each run
    traces again (the persistent compilation cache still saves the compile)."""

    def __init__(self, controller: Callable):
        self.controller = controller
        self._ticks = {}

    def bind(self, data: mujoco.MjData, carry, engine: bool) -> _BoundTick:
        """The tick of one run on ``data`` from ``carry`` (``engine``: as
        :func:`run_closed_loop`'s)."""
        fields = ENGINE_FIELDS if engine else ("qpos", "qvel")
        clock = np.zeros(1)
        # MjData's fields are views of its buffers: bound once, current at every gather.
        host = HostGather((clock, *(getattr(data, f)[None] for f in fields)))
        carry = jax.tree.map(jnp.asarray, carry)  # JAX's dtypes (float32 unless x64)
        carry_layout = TreeLayout.of(carry)
        key = (carry_layout, host.layout, engine)
        if key not in self._ticks:
            self._ticks[key] = self._jit_tick(carry_layout, host, engine)
        tick, logs = self._ticks[key]
        return _BoundTick(clock, host, tick, carry_layout, logs, carry)

    def _jit_tick(self, carry_layout: TreeLayout, host: HostGather, engine: bool):
        """The jitted tick and a dict that its trace fills with the log's layout (one trace,
        at the first call, gives both)."""
        controller = self.controller
        logs = {}

        def tick(row, packed):
            t, *values = host.unpack(row)
            state = carry_layout.unpack(packed)
            if engine:
                terms = EngineTerms(*values)
                torques, state, log = controller(t, terms.qpos, terms.qvel, state, engine=terms)
            else:
                torques, state, log = controller(t, *values, state)
            out_layout = TreeLayout.of(state)
            if out_layout != carry_layout:
                raise ValueError(
                    "run_closed_loop: the controller returns a carry of another structure, "
                    f"shape or dtype than it is given: {out_layout.describe()} against "
                    f"{carry_layout.describe()}"
                )
            logs["layout"] = TreeLayout.of(log)
            return torques, carry_layout.pack(state), logs["layout"].pack(log)

        # One robot: single-threaded kernels, XLA's own matrix products (runtime's notes).
        return jax.jit(tick, compiler_options=single_thread_compiler_options()), logs


class _BoundTick:
    """One run's tick: the packed carry stays on the device between ticks."""

    def __init__(self, clock, host, tick, carry_layout, logs, carry):
        self.clock, self.host, self.tick = clock, host, tick
        self.carry_layout, self._logs = carry_layout, logs
        self.packed = carry_layout.pack(carry, xp=np)

    def __call__(self, t: float):
        """``(torques, packed log)`` for the bound data's current state at time ``t``."""
        self.clock[0] = t
        try:
            torques, self.packed, log = self.tick(self.host.gather()[0], self.packed)
        except (jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError) as e:
            raise TypeError(
                "run_closed_loop: the controller is not a pure JAX function; pass pure=False "
                "to call it as a Python function"
            ) from e
        return torques, log

    @property
    def log_layout(self) -> TreeLayout:
        return self._logs["layout"]

    def log(self, packed: dict):
        """One tick's log as the controller's pytree (numpy)."""
        return self.log_layout.unpack({k: np.asarray(v) for k, v in packed.items()})

    def stacked(self, logs: list):
        """The ticks' logs, every leaf stacked over ticks (numpy); None for no tick."""
        if not logs:
            return None
        return self.log_layout.unpack(
            {k: np.stack([np.asarray(p[k]) for p in logs]) for k in self.log_layout.sizes()}
        )

    def carry(self):
        """The carry after the last tick (JAX arrays; the initial carry if none ran)."""
        return self.carry_layout.unpack({k: jnp.asarray(v) for k, v in self.packed.items()})
