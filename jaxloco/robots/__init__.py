"""Robot descriptions: what WBLC, the gait and the sweeps need to know about a humanoid
(:class:`RobotDescription`), and the robots jaxloco ships (:data:`ROBOTS`)."""

from jaxloco.robots.apollo import APOLLO
from jaxloco.robots.description import (
    PD,
    Foot,
    RobotDescription,
    TaskGains,
    check_model,
    com_height,
    effort_limits,
    robot_scale,
)
from jaxloco.robots.g1 import G1
from jaxloco.robots.valkyrie import VALKYRIE

ROBOTS = {robot.name: robot for robot in (VALKYRIE, G1, APOLLO)}
"""Shipped robots by name."""

DEFAULT_ROBOT = VALKYRIE
"""The robot a controller, gait or sweep is built for unless told otherwise."""


def robot_by_name(name: str) -> RobotDescription:
    """A shipped robot by name (a clear error naming the valid ones otherwise)."""
    if name not in ROBOTS:
        raise ValueError(f"robot: one of {sorted(ROBOTS)}, got {name!r}")
    return ROBOTS[name]


__all__ = [
    "APOLLO",
    "DEFAULT_ROBOT",
    "G1",
    "PD",
    "ROBOTS",
    "VALKYRIE",
    "Foot",
    "RobotDescription",
    "TaskGains",
    "check_model",
    "com_height",
    "effort_limits",
    "robot_by_name",
    "robot_scale",
]
