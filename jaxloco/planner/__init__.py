"""Phase-space planning on the linear inverted pendulum (paper Section II-A, Appendix A)."""

from jaxloco.planner import lipm, steering
from jaxloco.planner.lookahead import action_grid, make_lookahead_policy, nominal_distance_value
from jaxloco.planner.multistep import ComTrajectory, FootstepPlan, plan_steps, sample_com_trajectory
from jaxloco.planner.protocol import Planner
from jaxloco.planner.psp import (
    INFEASIBLE,
    SAFETY_MARGIN_NAMES,
    PSPParams,
    Reason,
    StepPlan,
    StepValidity,
    describe_reason,
    plan_from_com_state,
    plan_step,
    safety_margins,
    smooth_reward,
)
from jaxloco.planner.scaling import FroudeScale, scale_psp
from jaxloco.planner.steering import turn_schedule

__all__ = [
    "INFEASIBLE",
    "SAFETY_MARGIN_NAMES",
    "ComTrajectory",
    "FroudeScale",
    "FootstepPlan",
    "PSPParams",
    "Planner",
    "Reason",
    "StepPlan",
    "StepValidity",
    "action_grid",
    "describe_reason",
    "lipm",
    "make_lookahead_policy",
    "nominal_distance_value",
    "plan_from_com_state",
    "plan_step",
    "plan_steps",
    "safety_margins",
    "sample_com_trajectory",
    "scale_psp",
    "smooth_reward",
    "steering",
    "turn_schedule",
]
