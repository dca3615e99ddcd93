"""Walking on the full humanoid: gait state machine, swing trajectories, replanning, and the
walking controller that drives WBLC with the learned step planner (paper Section V-B/C)."""

from jaxloco.locomotion.gait import GaitReferences, GaitState
from jaxloco.locomotion.gait_params import GaitOverrides, GaitParams
from jaxloco.locomotion.swing import Motion, SwingSpline, make_swing, retarget_swing
from jaxloco.locomotion.walking import WalkingController, WalkingState, make_walking_controller
from jaxloco.locomotion.walking_log import WalkingLog

__all__ = [
    "GaitOverrides",
    "GaitParams",
    "GaitReferences",
    "GaitState",
    "Motion",
    "SwingSpline",
    "WalkingController",
    "WalkingLog",
    "WalkingState",
    "make_swing",
    "make_walking_controller",
    "retarget_swing",
]
