"""Apptronik Apollo (32 joints, 80.9 kg) from MuJoCo Menagerie's ``apptronik_apollo``
(Apache-2.0, in the model package's folder), as a :class:`RobotDescription`.

Edits by code (:mod:`jaxloco.robots.model_source`): the 32 position servos become torque
motors bounded by their own ``forcerange`` (hips up to 494 N m, knees 336, torso up to 414);
a ``walk`` keyframe is the ``stand`` one with the ankles turned until the soles (the plane
of each foot's four corner sites) are level, about 2 degrees, and the soles on the floor;
each foot's contact frame is added at the centroid of its corner sites, level in it (the
foot bodies' own frames are tilted); the base and torso get level frames; the timestep
goes from 5 ms to 1 ms, the controller's rate.
"""

from __future__ import annotations

from jaxloco.planner.scaling import FroudeScale
from jaxloco.robots.description import Foot, RobotDescription, TaskGains
from jaxloco.robots.model_source import AddedSite, FootSites, PackagedModel, StandingKeyframe

SIDES = ("left", "right")
PREFIX = {"left": "l", "right": "r"}
LEG_JOINTS = ("hip_ie", "hip_aa", "hip_fe", "knee_fe", "ankle_ie", "ankle_pd")
ARM_JOINTS = (
    "shoulder_aa",
    "shoulder_ie",
    "shoulder_fe",
    "elbow_fe",
    "wrist_roll",
    "wrist_yaw",
    "wrist_pitch",
)
TORSO_JOINTS = ("torso_yaw", "torso_roll", "torso_pitch")
NECK_JOINTS = ("neck_yaw", "neck_roll", "neck_pitch")


def _joints(side: str, names) -> tuple[str, ...]:
    return tuple(f"{PREFIX[side]}_{j}" for j in names)


APOLLO_JOINTS = (
    *TORSO_JOINTS,
    *NECK_JOINTS,
    *_joints("left", ARM_JOINTS),
    *_joints("right", ARM_JOINTS),
    *_joints("left", LEG_JOINTS),
    *_joints("right", LEG_JOINTS),
)
CORNER_SITES = {
    side: tuple(f"{PREFIX[side]}_foot_{c}" for c in ("fr", "br", "fl", "bl")) for side in SIDES
}
COP_SITES = {side: f"{side}_foot_cop" for side in SIDES}

APOLLO_MODEL = PackagedModel(
    folder="apptronik_apollo",
    file="scene.xml",
    feet=tuple(
        FootSites(
            f"{PREFIX[side]}_foot_link",
            COP_SITES[side],
            CORNER_SITES[side],
            ankle=(f"{PREFIX[side]}_ankle_pd", f"{PREFIX[side]}_ankle_ie"),
        )
        for side in SIDES
    ),
    sites=(AddedSite("base_frame", "base_link"), AddedSite("torso_frame", "torso_link")),
    keyframe="walk",
    standing=StandingKeyframe("walk", "stand"),
    timestep=0.001,
)

APOLLO_SCALE = FroudeScale(0.8284)
"""The robot's size relative to Valkyrie's: its CoM height above the soles in its keyframe,
0.885 m, over Valkyrie's 1.068 m (``robot_scale`` derives it from the model; a test checks
the two agree)."""

APOLLO = RobotDescription(
    name="apollo",
    model=APOLLO_MODEL,
    feet=tuple(Foot(side, COP_SITES[side], CORNER_SITES[side]) for side in SIDES),
    base_frame="base_frame",
    base_body="base_link",
    torso_frame="torso_frame",
    joints=APOLLO_JOINTS,
    upper_body_joints=(*TORSO_JOINTS, *NECK_JOINTS),
    arm_joints=tuple(j for side in SIDES for j in _joints(side, ARM_JOINTS)),
    partial_posture_joints=tuple(
        j for j in APOLLO_JOINTS if not j.endswith(("shoulder_fe", "shoulder_aa", "knee_fe"))
    ),
    keyframe="walk",
    torque_limits_in_qp=True,
    length_scale=APOLLO_SCALE.length,
    # Valkyrie's gains as they are: scaled to Apollo's size they commanded the legs far
    # past their limits and relaxed the friction cone (docs/robots.md).
    gains=TaskGains(),
    planner="apollo",
    fall_height=0.6,
    foot_friction=2.0,  # the contact pairs of its feet with the floor
)
