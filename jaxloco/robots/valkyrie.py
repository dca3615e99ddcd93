"""The Valkyrie-like humanoid shipped in ``assets/valkyrie`` as a :class:`RobotDescription`.

Its names (joints in the paper's order, feet, frames) live here and nowhere else in the
controller; see :mod:`jaxloco.dynamics.model` for the model itself.
"""

from __future__ import annotations

from jaxloco.robots.description import Foot, RobotDescription

LEG_JOINTS = ("hipYaw", "hipRoll", "hipPitch", "knee", "anklePitch", "ankleRoll")
ARM_JOINTS = ("shoulderPitch", "shoulderRoll", "shoulderYaw", "elbowPitch", "forearmYaw")
TORSO_JOINTS = ("torsoYaw", "torsoPitch", "torsoRoll")
NECK_JOINTS = ("lowerNeckPitch", "neckYaw", "upperNeckPitch")
SIDES = ("left", "right")

# The paper's joint order (after the 6 floating-base velocities).
VALKYRIE_JOINTS = (
    *(f"left_{j}" for j in LEG_JOINTS),
    *(f"right_{j}" for j in LEG_JOINTS),
    *TORSO_JOINTS,
    *(f"left_{j}" for j in ARM_JOINTS),
    *NECK_JOINTS,
    *(f"right_{j}" for j in ARM_JOINTS),
)
CONTACT_SITES = {side: tuple(f"{side}_foot_contact{k}" for k in range(4)) for side in SIDES}
COP_SITES = {side: f"{side}_foot_cop" for side in SIDES}

VALKYRIE = RobotDescription(
    name="valkyrie",
    model="valkyrie",
    feet=tuple(Foot(side, COP_SITES[side], CONTACT_SITES[side]) for side in SIDES),
    base_frame="pelvis",
    base_body="pelvis",
    torso_frame="torso",
    joints=VALKYRIE_JOINTS,
    upper_body_joints=(*TORSO_JOINTS, *NECK_JOINTS),
    arm_joints=tuple(f"{side}_{j}" for side in SIDES for j in ARM_JOINTS),
    partial_posture_joints=tuple(
        j for j in VALKYRIE_JOINTS if not j.endswith(("shoulderPitch", "shoulderRoll", "knee"))
    ),
    keyframe="walk",
    fall_height=0.7,
    torque_limit=500.0,  # the paper's authors' bound at every joint
    solver_iterations=(2, 4),  # PhysicsParams' defaults: every Valkyrie result used them
    length_scale=1.0,  # the reference robot: the default numbers were chosen for it
)
