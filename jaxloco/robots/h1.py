"""Unitree H1 (19 joints, 51.4 kg) from MuJoCo Menagerie's ``unitree_h1`` (Unitree's
BSD-3-Clause licence, in the model package's folder), as a :class:`RobotDescription` that
:func:`~jaxloco.robots.check_model` refuses: each leg has 5 joints (no ankle roll), and the
walking controller holds a flat stance foot with 6 constraints, which leaves a 5-joint
stance leg no motion to move the base with. It is not in :data:`jaxloco.robots.ROBOTS`; it
shows what the check says of such a robot.

The model ships torque motors already (control ranges up to 300 N m); the edits add each
foot's contact points at the corners of its sole (the bottoms of its capsule colliders) and
level frames.
"""

from __future__ import annotations

from jaxloco.robots.description import Foot, RobotDescription
from jaxloco.robots.model_source import AddedSite, FootSites, PackagedModel

SIDES = ("left", "right")
LEG_JOINTS = ("hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle")
ARM_JOINTS = ("shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow")
H1_JOINTS = (
    *(f"{side}_{j}" for side in SIDES for j in LEG_JOINTS),
    "torso",
    *(f"{side}_{j}" for side in SIDES for j in ARM_JOINTS),
)
CONTACT_SITES = {side: tuple(f"{side}_foot_contact{k}" for k in range(4)) for side in SIDES}
COP_SITES = {side: f"{side}_foot_cop" for side in SIDES}
# Sole corners in the ankle link (m): the capsules' ends, 14 mm radius below their axes.
SOLE_CORNERS = tuple((x, y, -0.0645) for x in (-0.05, 0.14) for y in (0.03, -0.03))

H1_MODEL = PackagedModel(
    folder="unitree_h1",
    file="scene.xml",
    feet=tuple(
        FootSites(
            f"{side}_ankle_link", COP_SITES[side], CONTACT_SITES[side], positions=SOLE_CORNERS
        )
        for side in SIDES
    ),
    sites=(AddedSite("pelvis_frame", "pelvis"), AddedSite("torso_frame", "torso_link")),
    keyframe="home",
)

H1 = RobotDescription(
    name="h1",
    model=H1_MODEL,
    feet=tuple(Foot(side, COP_SITES[side], CONTACT_SITES[side]) for side in SIDES),
    base_frame="pelvis_frame",
    base_body="pelvis",
    torso_frame="torso_frame",
    joints=H1_JOINTS,
    upper_body_joints=("torso",),
    arm_joints=tuple(f"{side}_{j}" for side in SIDES for j in ARM_JOINTS),
    partial_posture_joints=tuple(
        j for j in H1_JOINTS if not j.endswith(("shoulder_pitch", "shoulder_roll", "knee"))
    ),
    keyframe="home",
    fall_height=0.6,
)
