"""Gradient-based tuning of controller gains through differentiable rollouts."""

from jaxloco.tuning.gains import GainSpace, tuned_values
from jaxloco.tuning.optimize import TuneConfig, TuneResult, TuningDiverged, tune, tune_in_dir
from jaxloco.tuning.problems import PushLossParams, ShakingLossParams, push_loss, shaking_loss
from jaxloco.tuning.step_planner import GradientPlannerParams, make_gradient_policy

__all__ = [
    "GainSpace",
    "GradientPlannerParams",
    "PushLossParams",
    "ShakingLossParams",
    "TuneConfig",
    "TuneResult",
    "TuningDiverged",
    "make_gradient_policy",
    "push_loss",
    "shaking_loss",
    "tune",
    "tune_in_dir",
    "tuned_values",
]
