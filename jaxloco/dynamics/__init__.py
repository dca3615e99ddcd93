"""Dynamics on MJX data (paper Section IV): models, joint-space terms, task Jacobians,
Lie-group J-dot q-dot, centroidal momentum."""

from jaxloco.dynamics import se3
from jaxloco.dynamics.jacobians import (
    body_motion,
    com_jacobian,
    com_jdot_qdot,
    frame_jacobian,
    frame_jdot_qdot,
    point_jacobian,
    point_jdot_qdot,
    screw_axes,
    smooth,
)
from jaxloco.dynamics.model import keyframe_qpos, load_model, load_valkyrie
from jaxloco.dynamics.terms import JointSpaceTerms, joint_space_terms

__all__ = [
    "JointSpaceTerms",
    "body_motion",
    "com_jacobian",
    "com_jdot_qdot",
    "frame_jacobian",
    "frame_jdot_qdot",
    "joint_space_terms",
    "keyframe_qpos",
    "load_model",
    "load_valkyrie",
    "point_jacobian",
    "point_jdot_qdot",
    "screw_axes",
    "se3",
    "smooth",
]
