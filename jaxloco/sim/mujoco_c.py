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
import mujoco
import numpy as np
from tqdm.auto import tqdm

from jaxloco.dynamics.engine_terms import engine_terms

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
) -> tuple[ClosedLoopLog[Log], object]:
    """Run ``steps`` physics steps with ``ctrl = controller(t, qpos, qvel, carry)``.

    ``controller`` (jitted by the caller) returns ``(torques, carry, log)``; ``log`` is a
    pytree of arrays (e.g. a :class:`~jaxloco.locomotion.walking_log.WalkingLog`) recorded
    every step. ``stop(data)`` ends the run early (a fall).
    ``perturb(data)`` runs before every physics step (e.g. sets ``xfrc_applied`` for pushes);
    ``done(log)`` ends the run (not as a fall) when the controller's log says so.
    ``on_step(data)`` runs after every physics step (e.g. a :mod:`.viewer` redraw).
    ``engine``: each step is ``mj_step1``, the controller, ``mj_step2`` (the same physics
    as ``mj_step``), and the controller is called as ``controller(t, qpos, qvel, carry,
    engine=terms)`` with what ``mj_step1`` computed for the state
    (:class:`~jaxloco.dynamics.engine_terms.EngineTerms`), so it need not compute it again.
    Returns the log and the final carry.
    """
    if engine and model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4:
        raise ValueError("run_closed_loop: engine=True needs mj_step1/mj_step2, which RK4 lacks")
    times, qpos, qvel, ctrl, logs = [], [], [], [], []
    fell = False
    bar = tqdm(
        range(steps), desc=progress if isinstance(progress, str) else "sim", disable=not progress
    )
    for _ in bar:
        if engine:
            mujoco.mj_step1(model, data)
            terms = engine_terms(data)
            torques, carry, log = controller(data.time, terms.qpos, terms.qvel, carry, engine=terms)
        else:
            torques, carry, log = controller(data.time, data.qpos.copy(), data.qvel.copy(), carry)
        data.ctrl[:] = np.asarray(torques)
        times.append(data.time)
        qpos.append(data.qpos.copy())
        qvel.append(data.qvel.copy())
        ctrl.append(data.ctrl.copy())
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
        if done is not None and done(log):
            break
    outputs = (
        jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *logs) if logs else None
    )
    return (
        ClosedLoopLog(
            np.array(times), np.array(qpos), np.array(qvel), np.array(ctrl), outputs, fell
        ),
        carry,
    )
