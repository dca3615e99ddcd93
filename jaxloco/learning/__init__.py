"""RL-PSP: the RBF actor-critic step policy (paper Section II-B/C, Algorithm 1)."""

from jaxloco.learning.actor_critic import (
    ActorCriticConfig,
    TrainState,
    init_train_state,
    make_train_iteration,
)
from jaxloco.learning.checkpoint import (
    LearnedPlanner,
    load_checkpoint_config,
    save_checkpoint,
)
from jaxloco.learning.evaluation import (
    mean_policy,
    mean_weights_policy,
    steps_survived,
    survival_basin,
    value_function,
)
from jaxloco.learning.fallback import FallbackPlanner, make_fallback_planner
from jaxloco.learning.loading import (
    checkpoint_digest,
    load_planner,
    save_fallback_checkpoint,
    save_scaled_checkpoint,
)
from jaxloco.learning.rbf import RBFGrid
from jaxloco.learning.refine import RefineConfig, RefineResult, refine
from jaxloco.learning.starts import EpisodeTurns, StartStates
from jaxloco.learning.training import (
    FAST,
    STEERING,
    WARM_START,
    EvalConfig,
    TrainConfig,
    TrainResult,
    train,
)

__all__ = [
    "FallbackPlanner",
    "checkpoint_digest",
    "make_fallback_planner",
    "save_fallback_checkpoint",
    "save_scaled_checkpoint",
    "FAST",
    "ActorCriticConfig",
    "EpisodeTurns",
    "EvalConfig",
    "LearnedPlanner",
    "RBFGrid",
    "RefineConfig",
    "RefineResult",
    "STEERING",
    "StartStates",
    "TrainConfig",
    "TrainResult",
    "TrainState",
    "WARM_START",
    "init_train_state",
    "load_checkpoint_config",
    "load_planner",
    "make_train_iteration",
    "mean_policy",
    "mean_weights_policy",
    "refine",
    "save_checkpoint",
    "steps_survived",
    "survival_basin",
    "train",
    "value_function",
]
