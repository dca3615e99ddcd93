"""WBLC configurations built from a :class:`~jaxloco.robots.RobotDescription`: the paper's
task sets as data.

- :func:`walking_config`: the walking hierarchy of Section V-B (CoM -> pelvis -> body ->
  swing-foot orientation -> swing-foot position -> neck and torso posture -> CAM -> arms).
- :func:`body_shaking_config`: Section V-A's six tasks with Eq. 32's ``H1`` or ``H2``.

Each starts with the contact constraint (see :mod:`jaxloco.control.wblc`). Task names are
the robot's foot names plus fixed suffixes (``left_contact``, ``left_foot_pos``...), so the
same hierarchies name every robot's tasks. Default gains come from the description
(:class:`~jaxloco.robots.TaskGains`).
"""

from __future__ import annotations

import dataclasses

from jaxloco.control.force_qp import ForceQPParams
from jaxloco.control.tasks import TaskSpec
from jaxloco.control.wblc import FootSpec, WBLCConfig
from jaxloco.robots import DEFAULT_ROBOT, RobotDescription

SIDES = ("left", "right")
"""How the hierarchies name a robot's two feet (its ``feet`` in order)."""


def foot_task(k: int, suffix: str) -> str:
    """The name of foot ``k``'s task (0: left, 1: right), e.g. ``left_foot_pos``."""
    return f"{SIDES[k]}_{suffix}"


def robot_feet(robot: RobotDescription) -> tuple[FootSpec, ...]:
    return tuple(FootSpec(foot.frame, foot.points) for foot in robot.feet)


def robot_tasks(robot: RobotDescription = DEFAULT_ROBOT) -> tuple[TaskSpec, ...]:
    """Every task the presets use, with the robot's default gains."""
    g = robot.gains
    feet = tuple(
        spec
        for k, foot in enumerate(robot.feet)
        for spec in (
            _frame_task(foot_task(k, "foot_ori"), "orientation", foot.frame, g.foot_orientation),
            _frame_task(foot_task(k, "foot_pos"), "position", foot.frame, g.foot_position),
        )
    )
    joint_groups = (
        ("neck_torso", robot.upper_body_joints),
        ("arms", robot.arm_joints),
        ("partial_posture", robot.partial_posture_joints),
        ("full_posture", robot.joints),
    )
    return (
        *(
            _frame_task(foot_task(k, "contact"), "contact", foot.frame, g.contact)
            for k, foot in enumerate(robot.feet)
        ),
        TaskSpec("com", "com", kp=g.com.kp, kd=g.com.kd),
        TaskSpec("cam", "cam", kp=g.cam.kp, kd=g.cam.kd),
        _frame_task("pelvis_ori", "orientation", robot.base_frame, g.base_orientation),
        _frame_task("body_ori", "orientation", robot.torso_frame, g.torso_orientation),
        *feet,
        *(
            TaskSpec(name, "joints", joints=joints, kp=g.posture.kp, kd=g.posture.kd)
            for name, joints in joint_groups
        ),
    )


def _frame_task(name: str, kind: str, frame: str, pd) -> TaskSpec:
    return TaskSpec(name, kind, frame=frame, kp=pd.kp, kd=pd.kd)


CONTACT = "left_contact+right_contact"
WALKING = (
    CONTACT,
    "com",
    "pelvis_ori",
    "body_ori",
    "left_foot_ori|right_foot_ori",
    "left_foot_pos|right_foot_pos",
    "neck_torso",
    "cam",
    "arms",
)
H1 = (CONTACT, "com", "cam", "body_ori", "partial_posture", "pelvis_ori", "full_posture")
H2 = (CONTACT, "com", "body_ori", "partial_posture", "pelvis_ori", "cam", "full_posture")
HIERARCHIES = {"walking": WALKING, "H1": H1, "H2": H2}


def wblc_config(
    hierarchy: str | tuple[str, ...] = "walking",
    robot: RobotDescription = DEFAULT_ROBOT,
    **overrides,
) -> WBLCConfig:
    """A WBLC config for ``robot``; ``hierarchy`` is a preset name or a tuple of levels."""
    if isinstance(hierarchy, str):
        if hierarchy not in HIERARCHIES:
            raise ValueError(f"hierarchy: one of {sorted(HIERARCHIES)} or a tuple of levels")
        hierarchy = HIERARCHIES[hierarchy]
    overrides.setdefault("force_qp", robot_force_qp(robot))
    return WBLCConfig(
        tasks=robot_tasks(robot), hierarchy=tuple(hierarchy), feet=robot_feet(robot), **overrides
    )


PAPER_FLOOR_FRICTION = 0.8
"""The friction of the floor the paper's authors simulated on, for which their force QP
planned with ``mu`` 0.65, relaxed to 1.75 (``ForceQPParams``' defaults)."""


def robot_force_qp(robot: RobotDescription, params: ForceQPParams | None = None) -> ForceQPParams:
    """``params`` (default ``ForceQPParams()``) with friction pyramids in the same
    proportion to ``robot``'s foot friction as the authors' to their floor's: ``mu`` and
    ``mu_relaxed`` times ``robot.foot_friction / 0.8`` (the paper's robot: unchanged; feet
    of friction 0.6 get 0.49 and 1.31 instead of forces their floor does not give)."""
    params = ForceQPParams() if params is None else params
    ratio = robot.foot_friction / PAPER_FLOOR_FRICTION
    if ratio == 1.0:
        return params
    return dataclasses.replace(params, mu=params.mu * ratio, mu_relaxed=params.mu_relaxed * ratio)


# The walking controller's force QP runs every tick from the previous tick's solution, so
# it needs fewer iterations than a cold solve (ForceQPParams' defaults, which meet the
# accuracy target against quadprog from a cold start), and a smaller penalty suits it: warm,
# the iterate starts near the solution, and a smaller rho moves it along the active
# constraints faster. tests/test_force_qp.py bounds its error along a 1 kHz sequence of
# problems (measurements in docs/control.md).
CLOSED_LOOP_QP = ForceQPParams(iterations=150, rho=0.02)

# With torque rows (the robots whose legs are kept within their limits in the force QP),
# each iteration costs more (a 40 x 40 mat-vec instead of 24 x 24 on the G1). Half the
# iterations, at a larger penalty with the rows' own equal to it: along the G1's pushed
# walks the torques are about as far from a converged solve (2000 iterations) as with
# CLOSED_LOOP_QP's settings (within 0.2 N m at the median tick, 16-25 N m at the 99th
# percentile for both); where the limits bind on most ticks the forces are further off
# (median 0.39 N against 0.12). Measurements in docs/control.md.
CLOSED_LOOP_TORQUE_QP = ForceQPParams(iterations=75, rho=0.06, torque_rho=1.0)


def walking_force_qp(robot: RobotDescription, torque_rows: bool | None = None) -> ForceQPParams:
    """The walking controller's force QP for ``robot``: ``CLOSED_LOOP_TORQUE_QP`` with torque
    rows (``torque_rows``; None: the robot's ``torque_limits_in_qp``), else
    ``CLOSED_LOOP_QP``, with the robot's friction pyramids (:func:`robot_force_qp`)."""
    rows = robot.torque_limits_in_qp if torque_rows is None else torque_rows
    return robot_force_qp(robot, CLOSED_LOOP_TORQUE_QP if rows else CLOSED_LOOP_QP)


# Damped inverses at the walking hierarchy's first and last levels, truncated between. The
# first level (the contact constraint) is not projected, so its whitened Gram matrix is the
# identity on the rows in contact: both inverses give it, to 1e-4. The last (arms) only
# shapes the null space. Those are the two largest levels (12 and 14 rows), whose
# eigendecompositions cost the most; damped at every level lost a push of a criterion
# sweep that the truncated middle levels recover (docs/control.md).
WALKING_INVERSES = ("damped",) + ("truncated",) * (len(WALKING) - 2) + ("damped",)


def walking_config(robot: RobotDescription = DEFAULT_ROBOT, **overrides) -> WBLCConfig:
    """The walking hierarchy with the warm-started force QP settings (:func:`walking_force_qp`:
    ``CLOSED_LOOP_QP``, or ``CLOSED_LOOP_TORQUE_QP`` with torque rows; the friction
    pyramids the robot's), damped inverses at its first and last levels
    (``WALKING_INVERSES``), and the robot's defaults for torque rows in the force QP and
    the whole-body limit stage (``torque_limits_in_qp``, ``whole_body_limits``; None: the
    robot's)."""
    for field in ("torque_limits_in_qp", "whole_body_limits"):
        if overrides.get(field) is None:
            overrides[field] = getattr(robot, field)
    overrides.setdefault("force_qp", walking_force_qp(robot, overrides["torque_limits_in_qp"]))
    overrides.setdefault("hierarchy_inverse", WALKING_INVERSES)
    return wblc_config("walking", robot, **overrides)


def body_shaking_config(
    which: str = "H2", robot: RobotDescription = DEFAULT_ROBOT, **overrides
) -> WBLCConfig:
    if which not in ("H1", "H2"):
        raise ValueError(f"body_shaking_config: which must be 'H1' or 'H2', got {which!r}")
    return wblc_config(which, robot, **overrides)
