"""Unitree G1 (29 joints, 33.3 kg) from MuJoCo Menagerie's ``unitree_g1`` (Unitree's BSD-3-Clause
licence, in the model package's folder), as a :class:`RobotDescription`.

Edits by code (:mod:`jaxloco.robots.model_source`): the 29 position servos become torque
motors bounded by each joint's ``actuatorfrcrange`` (hips 88-139 N m, knees 139, ankles 50);
each foot gets a contact point at the bottom of each of its four 5 mm contact spheres and a
centre-of-pressure frame between them; the pelvis and torso get level frames; a ``walk``
keyframe bends the legs (hip pitch -0.3, knee 0.6, ankle pitch -0.3 rad) with the soles on
the floor. The timestep stays 2 ms: the controller runs at 500 Hz on this robot.
"""

from __future__ import annotations

from jaxloco.planner.scaling import FroudeScale
from jaxloco.robots.description import Foot, RobotDescription, TaskGains
from jaxloco.robots.model_source import AddedSite, FootSites, PackagedModel, StandingKeyframe

SIDES = ("left", "right")
LEG_JOINTS = ("hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch", "ankle_roll")
WAIST_JOINTS = ("waist_yaw", "waist_roll", "waist_pitch")
ARM_JOINTS = (
    "shoulder_pitch",
    "shoulder_roll",
    "shoulder_yaw",
    "elbow",
    "wrist_roll",
    "wrist_pitch",
    "wrist_yaw",
)


def _joints(side: str, names) -> tuple[str, ...]:
    return tuple(f"{side}_{j}_joint" for j in names)


G1_JOINTS = (
    *_joints("left", LEG_JOINTS),
    *_joints("right", LEG_JOINTS),
    *(f"{j}_joint" for j in WAIST_JOINTS),
    *_joints("left", ARM_JOINTS),
    *_joints("right", ARM_JOINTS),
)
CONTACT_SITES = {side: tuple(f"{side}_foot_contact{k}" for k in range(4)) for side in SIDES}
COP_SITES = {side: f"{side}_foot_cop" for side in SIDES}
WALK_POSTURE = tuple(
    (f"{side}_{joint}_joint", angle)
    for side in SIDES
    for joint, angle in (("hip_pitch", -0.3), ("knee", 0.6), ("ankle_pitch", -0.3))
)

G1_MODEL = PackagedModel(
    folder="unitree_g1",
    file="scene.xml",
    feet=tuple(
        FootSites(f"{side}_ankle_roll_link", COP_SITES[side], CONTACT_SITES[side], True)
        for side in SIDES
    ),
    sites=(AddedSite("pelvis_frame", "pelvis"), AddedSite("torso_frame", "torso_link")),
    keyframe="walk",
    standing=StandingKeyframe("walk", "stand", WALK_POSTURE),
)

G1_SCALE = FroudeScale(0.6293)
"""The robot's size relative to Valkyrie's: its CoM height above the soles in its keyframe,
0.672 m, over Valkyrie's 1.068 m (``robot_scale`` derives it from the model; a test checks
the two agree)."""

G1 = RobotDescription(
    name="g1",
    model=G1_MODEL,
    feet=tuple(Foot(side, COP_SITES[side], CONTACT_SITES[side]) for side in SIDES),
    base_frame="pelvis_frame",
    base_body="pelvis",
    torso_frame="torso_frame",
    joints=G1_JOINTS,
    upper_body_joints=tuple(f"{j}_joint" for j in WAIST_JOINTS),
    arm_joints=tuple(j for side in SIDES for j in _joints(side, ARM_JOINTS)),
    partial_posture_joints=tuple(
        j
        for j in G1_JOINTS
        if not j.endswith(("shoulder_pitch_joint", "shoulder_roll_joint", "knee_joint"))
    ),
    keyframe="walk",
    torque_limits_in_qp=True,
    length_scale=G1_SCALE.length,
    gains=TaskGains().scaled(G1_SCALE),  # Valkyrie's gains at this size (Froude scaling)
    planner="g1",
    fall_height=0.45,
    foot_friction=0.6,  # the contact spheres of its feet (priority 1)
)
