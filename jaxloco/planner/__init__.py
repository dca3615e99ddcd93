"""Phase-space planning on the linear inverted pendulum (paper Section II-A, Appendix A)."""

from jaxloco.planner import lipm, steering
from jaxloco.planner.lookahead import action_grid, make_lookahead_policy, nominal_distance_value
from jaxloco.planner.multistep import ComTrajectory, FootstepPlan, plan_steps, sample_com_trajectory
from jaxloco.planner.psp import (
    INFEASIBLE,
    PSPParams,
    Reason,
    StepPlan,
    StepValidity,
    describe_reason,
    plan_from_com_state,
    plan_step,
)
from jaxloco.planner.steering import turn_schedule

__all__ = [
    "INFEASIBLE",
    "ComTrajectory",
    "FootstepPlan",
    "PSPParams",
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
    "sample_com_trajectory",
    "steering",
    "turn_schedule",
]
