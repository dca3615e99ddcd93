"""Training the RL-PSP planner: the loop around the jitted iteration, with a progress bar,
stopping rules, periodic survival-basin evaluation and best-policy keeping.

Presets:

- ``ActorCriticConfig()``: Algorithm 1 as the paper's authors ran it (plain summed updates,
  alpha = beta = 3e-5, initial spreads ~1.1). Learns very slowly when batched.
- :data:`FAST` (the default of :class:`TrainConfig`): the same update direction with
  per-cell averaging, a natural-gradient actor, normalised and clipped advantages, a
  cautious spread step and a narrow start around the nominal action. Each of these options
  is documented on :class:`~jaxloco.learning.actor_critic.ActorCriticConfig`.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxloco.learning import rbf
from jaxloco.learning.actor_critic import (
    ActorCriticConfig,
    TrainState,
    init_train_state,
    make_train_iteration,
)
from jaxloco.learning.evaluation import mean_policy, survival_basin
from jaxloco.learning.starts import StartStates
from jaxloco.planner import PSPParams

FAST = ActorCriticConfig(
    alpha=0.05,
    beta=0.05,
    episodes_per_iteration=256,
    max_episode_steps=10,
    max_iterations=600,
    optimizer="sgd",
    normalize="visits",
    natural_gradient=True,
    normalize_advantage=True,
    advantage_std_floor=3.0,
    spread_step_scale=0.2,
    initial_spread=0.1,
    # Tighter than the paper's 0.07: with this preset the spreads pass 0.07 while the
    # survival basin is still rising (measured: 34.5% there, ~40% a few hundred iterations on).
    spread_target=0.05,
)


@dataclasses.dataclass(frozen=True)
class EvalConfig:
    """Periodic evaluation during training (the survival basin of the mean policy)."""

    every: int = 25
    """Evaluate every this many iterations (0: never; the final policy is then kept)."""
    num_states: int = 2048
    num_steps: int = 50
    seed: int = 12345
    """Fixed draw of box states, the same at every evaluation (and unlike the training seed)."""

    def __post_init__(self):
        if self.every < 0 or self.num_states < 1 or self.num_steps < 1:
            raise ValueError(
                "EvalConfig: every must be >= 0, num_states and num_steps >= 1; "
                f"got {self.every}, {self.num_states}, {self.num_steps}"
            )


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything a training run depends on (saved with every checkpoint)."""

    actor_critic: ActorCriticConfig = FAST
    grid: rbf.RBFGrid = rbf.RBFGrid()
    starts: StartStates = StartStates()
    planner: PSPParams = PSPParams()
    evaluation: EvalConfig = EvalConfig()


@dataclasses.dataclass
class TrainResult:
    state: TrainState
    """The final training state."""
    best_params: object
    """The weights with the best evaluated basin (the final ones if never evaluated)."""
    best_basin: float | None
    history: list[dict]
    compile_seconds: float
    train_seconds: float
    """Wall time of the iterations after the first (compile excluded), evaluation excluded."""
    eval_seconds: float
    stop_reason: str


def train(config: TrainConfig = TrainConfig(), progress: bool = True, state=None) -> TrainResult:
    """Run Algorithm 1 batched until every mean spread is below the target, or the budget.

    ``state``: resume from this :class:`TrainState` (e.g. a loaded checkpoint).
    """
    ac, grid, psp = config.actor_critic, config.grid, config.planner
    iteration = make_train_iteration(ac, grid, psp, config.starts)
    evaluate = jax.jit(
        lambda params: survival_basin(
            mean_policy(params, grid, psp),
            psp,
            jax.random.key(config.evaluation.seed),
            config.evaluation.num_states,
            config.evaluation.num_steps,
            config.starts,
        )[0]
    )
    state = init_train_state(ac, grid) if state is None else state
    # Each iteration's key depends only on (seed, iteration): a resumed run draws exactly
    # what an uninterrupted one would have.
    base_key = jax.random.key(ac.seed)
    start_iteration = int(state.iteration)
    remaining = ac.max_iterations - start_iteration

    bar = _progress_bar(remaining, progress)
    history, best_params, best_basin = [], state.params, None
    compile_s = train_s = eval_s = 0.0
    stop_reason = "iteration budget"
    t_run = time.perf_counter()
    for i in range(remaining):
        k = jax.random.fold_in(base_key, int(state.iteration))
        t0 = time.perf_counter()
        state, stats = iteration(state, k)
        jax.block_until_ready(state.params)
        dt = time.perf_counter() - t0
        if i == 0:
            compile_s = dt
        else:
            train_s += dt
        row = {
            "iteration": int(state.iteration),
            "wall_s": time.perf_counter() - t_run,
            "mean_return": float(stats.mean_return),
            "survival": float(stats.survival),
            "mean_length": float(stats.mean_length),
            "spread": [float(x) for x in stats.spread],
            "mean_abs_td": float(stats.mean_abs_td),
        }
        if not np.all(np.isfinite(row["spread"])) or not np.isfinite(row["mean_return"]):
            stop_reason = "non-finite statistics (diverged)"
            history.append(row)
            break
        every = config.evaluation.every
        last = i == remaining - 1
        spreads_done = max(row["spread"]) < ac.spread_target
        if every and (int(state.iteration) % every == 0 or last or spreads_done):
            t0 = time.perf_counter()
            basin = float(evaluate(state.params))
            eval_s += time.perf_counter() - t0
            row["basin"] = basin
            if best_basin is None or basin > best_basin:
                best_basin, best_params = basin, state.params
        history.append(row)
        bar.set_postfix(
            ret=f"{row['mean_return']:.2f}",
            surv=f"{row['survival']:.2f}",
            spread=f"{max(row['spread']):.3f}",
            basin=f"{best_basin:.3f}" if best_basin is not None else "-",
        )
        bar.update(1)
        if spreads_done:
            stop_reason = f"every mean spread < {ac.spread_target}"
            break
    bar.close()
    if best_basin is None:
        best_params = state.params
    return TrainResult(
        state=state,
        best_params=best_params,
        best_basin=best_basin,
        history=history,
        compile_seconds=compile_s,
        train_seconds=train_s,
        eval_seconds=eval_s,
        stop_reason=stop_reason if start_iteration < ac.max_iterations else "already done",
    )


def _progress_bar(total: int, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, desc="RL-PSP", unit="it", disable=not enabled, leave=True)


def params_fingerprint(params) -> str:
    """A short hash of the weights (reproducibility checks)."""
    import hashlib

    h = hashlib.sha256()
    for leaf in jax.tree.leaves(params):
        h.update(np.asarray(jnp.asarray(leaf)).tobytes())
    return h.hexdigest()[:16]
