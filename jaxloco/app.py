"""What the experiment apps in ``experiments/`` share: the fields of every run config and
the set-up around a run.

An experiment is a config dataclass deriving :class:`RunConfig`, registered with
:func:`register`, and a function ``run(cfg, out_dir) -> summary``; its hydra main calls
:func:`run_in_hydra`, and its script calls :func:`launch`::

    register("body_shaking", BodyShakingConfig)

    @hydra.main(version_base="1.3", config_path=None, config_name="body_shaking")
    def main(cfg) -> None:
        summary, out_dir = run_in_hydra(cfg, run)
        print(...)

    if __name__ == "__main__":
        launch(main)

(The ``hydra.main`` decorator stays in the script: hydra names the job after the file that
defines the decorated function.)
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import mujoco
from hydra.core.config_store import ConfigStore
from hydra.core.hydra_config import HydraConfig
from omegaconf import OmegaConf

from jaxloco.control.presets import walking_force_qp
from jaxloco.locomotion.gait_params import GaitParams
from jaxloco.locomotion.walking import robot_gait
from jaxloco.robots import RobotDescription, robot_by_name
from jaxloco.runtime import configure, enable_compilation_cache, quiet_library_logs, watchdog
from jaxloco.sweep.limit_search import PAPER_MASS


@dataclass
class RunConfig:
    """Fields every experiment's config has."""

    timeout_s: float = 3600.0
    """Watchdog (s): past it the run stops and dumps every thread's stack (XLA on CPU has
    been seen to hang in ``block_until_ready``)."""
    dpi: int = 130
    """Resolution of the figures written (dots per inch)."""


ROBOT_DEFAULTS = (
    "torque_limit",
    "iterations",
    "ls_iterations",
    "fall_height",
    "impulse_high",
    "mu",
    "mu_relaxed",
    "qp_iterations",
    "qp_rho",
    "qp_torque_rho",
)
"""The config values that default to the config's ``robot``'s (:func:`robot_default`)."""

FORCE_QP_DEFAULTS = {
    "mu": "mu",
    "mu_relaxed": "mu_relaxed",
    "iterations": "qp_iterations",
    "rho": "qp_rho",
    "torque_rho": "qp_torque_rho",
}
"""The walking force QP's fields that default to the robot's (the force QP node's field:
its :data:`ROBOT_DEFAULTS` name)."""

REFERENCE_IMPULSE_HIGH = 256.0
"""The limit search's default top impulse (N s), chosen for Valkyrie (``PAPER_MASS``)."""


def robot_default(field: str) -> str:
    """A config value: the config's ``robot``'s default for ``field``, resolved when the
    config is read: the simulation's ``torque_limit``, solver ``iterations`` and
    ``ls_iterations`` (:class:`~jaxloco.robots.RobotDescription`), the ``fall_height`` of its
    base, ``impulse_high``, the limit search's top impulse (N s): 256 N s for Valkyrie,
    the same velocity change (impulse / mass) for another robot, rounded up to 16 N s, and
    the walking force QP's friction pyramids ``mu``, ``mu_relaxed`` and its solver's
    ``qp_iterations``, ``qp_rho``, ``qp_torque_rho``
    (:func:`~jaxloco.control.presets.walking_force_qp`: with torque rows for the robots that
    keep them by default)."""
    if field not in ROBOT_DEFAULTS:
        raise ValueError(f"robot_default: field must be one of {ROBOT_DEFAULTS}; got {field!r}")
    return "${jaxloco_robot:${robot}," + field + "}"


def _robot_value(name: str, field: str):
    robot = robot_by_name(name)
    if field == "torque_limit":
        return robot.torque_limit
    if field in ("iterations", "ls_iterations"):
        return robot.solver_iterations[ROBOT_DEFAULTS.index(field) - 1]
    if field == "fall_height":
        return robot.fall_height
    if field in ("mu", "mu_relaxed"):
        return getattr(walking_force_qp(robot), field)
    if field in ("qp_iterations", "qp_rho", "qp_torque_rho"):
        return getattr(walking_force_qp(robot), field[3:])
    if field == "impulse_high":
        if robot.length_scale == 1.0:  # the reference robot: the bracket as chosen
            return REFERENCE_IMPULSE_HIGH
        mass = float(robot.load().body_subtreemass[0])
        # The same velocity change, up to a multiple of 16 N s: round bisection steps.
        return 16.0 * math.ceil(REFERENCE_IMPULSE_HIGH * mass / PAPER_MASS / 16.0)
    raise ValueError(f"robot_default: field must be one of {ROBOT_DEFAULTS}; got {field!r}")


def register(name: str, node: type, group: str | None = None) -> None:
    """Make the config dataclass ``node`` hydra's config ``name`` (in config group
    ``group``: an option picked by ``group=name`` on the command line), and the resolver
    behind :func:`robot_default`."""
    ConfigStore.instance().store(name=name, node=node, group=group)
    if not OmegaConf.has_resolver("jaxloco_robot"):
        OmegaConf.register_new_resolver("jaxloco_robot", _robot_value)


def robot_physics_schema(schema: type):
    """A default factory for an experiment's ``physics`` node (a ``config_schema`` of
    :class:`~jaxloco.sim.mjx_loop.PhysicsParams`) whose torque limit and solver iterations
    are the config's ``robot``'s defaults."""
    fields = ("torque_limit", "iterations", "ls_iterations")
    return lambda: schema(**{f: robot_default(f) for f in fields})


def robot_force_qp_schema(schema: type):
    """A default factory for an experiment's ``force_qp`` node (a ``config_schema`` of
    :class:`~jaxloco.control.force_qp.ForceQPParams` with ``CLOSED_LOOP_QP``'s defaults)
    whose friction pyramids and solver settings (:data:`FORCE_QP_DEFAULTS`) are the
    config's ``robot``'s walking force QP's (:func:`~jaxloco.control.presets.walking_force_qp`)."""
    return lambda: schema(**{f: robot_default(d) for f, d in FORCE_QP_DEFAULTS.items()})


class RobotSetup(NamedTuple):
    """What an experiment builds its controller from."""

    robot: RobotDescription
    """The robot's description."""
    model: mujoco.MjModel
    """The robot's model, checked against its description."""
    gait: GaitParams
    """The gait numbers at the robot's size."""


def robot_setup(name: str, gait: GaitParams | None = None) -> RobotSetup:
    """The shipped robot ``name``, its model, and ``gait`` (reference-size numbers, e.g. a
    config's; default ``GaitParams()``) scaled to its size."""
    robot = robot_by_name(name)
    model = robot.load()
    return RobotSetup(robot, model, robot_gait(robot, model, gait))


def run_in_hydra(cfg, run: Callable, as_object: bool = True) -> tuple[dict, Path]:
    """Inside a hydra main: quiet the libraries' INFO lines (:func:`quiet_library_logs`),
    turn on the compile cache, and call ``run(config, out_dir)`` under the watchdog
    (``cfg.timeout_s``), with hydra's run directory and the config as its dataclass
    (``as_object``) or as hydra's node. Returns the summary and the directory."""
    quiet_library_logs()
    enable_compilation_cache()
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    config = OmegaConf.to_object(cfg) if as_object else cfg
    with watchdog(config.timeout_s, HydraConfig.get().job.name):
        summary = run(config, out_dir)
    return summary, out_dir


def launch(main: Callable[[], None]) -> None:
    """Run a hydra main as a script: jaxloco's XLA options first (before JAX computes)."""
    configure()
    main()
