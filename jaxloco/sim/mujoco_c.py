"""Closed loop on MuJoCo's C engine for one robot: ``mj_step`` plus a jitted controller.

The reference backend (and the debugging one): the controller is the same pure function
that MJX rollouts vmap, called once per physics step from Python. Pure torque control; the
control rate is the model's timestep (1 kHz for Valkyrie).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import mujoco
import numpy as np
from tqdm.auto import tqdm


@dataclasses.dataclass
class ClosedLoopLog:
    time: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    ctrl: np.ndarray
    outputs: dict
    """Each entry the controller's per-step ``log`` output, stacked over time."""
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
    done: Callable[[dict], bool] | None = None,
) -> tuple[ClosedLoopLog, object]:
    """Run ``steps`` physics steps with ``ctrl = controller(t, qpos, qvel, carry)``.

    ``controller`` (jitted by the caller) returns ``(torques, carry, log)``; ``log`` is a
    dict of arrays recorded every step. ``stop(data)`` ends the run early (a fall).
    ``perturb(data)`` runs before every physics step (e.g. sets ``xfrc_applied`` for pushes);
    ``done(log)`` ends the run (not as a fall) when the controller's log says so.
    Returns the log and the final carry.
    """
    times, qpos, qvel, ctrl, logs = [], [], [], [], []
    fell = False
    bar = tqdm(
        range(steps), desc=progress if isinstance(progress, str) else "sim", disable=not progress
    )
    for _ in bar:
        torques, carry, log = controller(data.time, data.qpos.copy(), data.qvel.copy(), carry)
        data.ctrl[:] = np.asarray(torques)
        times.append(data.time)
        qpos.append(data.qpos.copy())
        qvel.append(data.qvel.copy())
        ctrl.append(data.ctrl.copy())
        logs.append(log)
        if perturb is not None:
            perturb(data)
        mujoco.mj_step(model, data)
        if not np.all(np.isfinite(data.qpos)) or (stop is not None and stop(data)):
            fell = True
            break
        if done is not None and done(log):
            break
    outputs = jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *logs) if logs else {}
    return (
        ClosedLoopLog(
            np.array(times), np.array(qpos), np.array(qvel), np.array(ctrl), outputs, fell
        ),
        carry,
    )
