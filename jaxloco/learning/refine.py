"""Refining the learned step policy through the differentiable planner (after Algorithm 1).

Algorithm 1 improves the actor with a likelihood-ratio gradient: it samples actions and
weighs their scores by TD errors. The PSP, though, is an analytic, differentiable model
(:func:`~jaxloco.planner.plan_step`), so the mean policy can also be improved by the
*pathwise* gradient: roll the deterministic policy ``horizon`` steps from a batch of apex
states and ascend, through every step, a smooth stand-in for "steps survived":

    J(theta) = mean_s0  sum_k  discount^k [ S_k  +  reward_weight * alive_k * clip(r_k, -10, 0) ]

- ``S_k = prod_{j <= k} prod_i sigmoid(sharpness * (m_ji - margin))``: a soft probability
  that steps ``0..k`` are all safe, from the signed margins ``m_ji`` inside Eq. 4's bounds
  and the stride bounds (:func:`~jaxloco.planner.safety_margins`; a step whose equations
  have no solution counts ``exp(infeasible_log_safety)``). It saturates on both sides, so
  hopeless states (no safe action) and comfortable ones pull little; the gradient comes
  from states near the edge of what is recoverable, which is where the survival basin is
  decided.
- ``r_k``: Eq. 3 without its terminal switch (:func:`~jaxloco.planner.smooth_reward`),
  counted only while the hard-checked steps are safe (``alive_k``, not differentiated): it
  keeps the walk near the nominal gait once survival is assured.

The start states are uniform draws over the box of Eq. 1, the distribution the survival
basin is measured on. Only the actor's mean channels (and their bias) change; the value and
the spreads stay as Algorithm 1 left them. Adam (optax), optionally with global-norm
clipping; the running average of the weights is what is evaluated, and the best evaluated
one is kept, as in training.

Why it exists: Algorithm 1 (batched, :data:`~jaxloco.learning.training.FAST`) plateaus
below a 0.5 survival basin, and least-squares imitation of a better search policy by the
same RBF does little better, while this refinement takes the same network past 0.5
(docs/learning.md). It is not in the paper.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time

import jax
import jax.numpy as jnp
import optax
from tqdm.auto import tqdm

from jaxloco import validation as v
from jaxloco.learning import policy as pol
from jaxloco.learning.evaluation import mean_weights_policy, steps_survived
from jaxloco.learning.starts import StartStates, uniform_states
from jaxloco.planner import PSPParams, plan_step, safety_margins, smooth_reward
from jaxloco.runtime import cpu_compiler_options


@dataclasses.dataclass(frozen=True)
class RefineConfig:
    """Pathwise refinement of the mean policy (see the module docstring)."""

    iterations: int = 200
    """Adam steps; 0 turns refinement off (Algorithm 1 alone, as the paper)."""
    batch: int = 2048
    """Start states per step (uniform over the box of Eq. 1, fresh each step)."""
    horizon: int = 2
    """Steps each start state is rolled through the planner (>= 2: one step does not
    learn). 4 steps reach the same basin at twice the cost per step; longer horizons gained
    nothing (docs/learning.md)."""
    learning_rate: float = 1e-3
    """Adam's step size."""
    adam_eps: float = 1e-8
    """Adam's denominator floor."""
    clip_norm: float = 0.0
    """Global-norm clip of each gradient (0: none)."""
    margin: float = 0.01
    """Safety margin (s for the times, m for p_y and the stride) at which a step counts
    sigmoid(0) = 1/2 safe."""
    sharpness: float = 100.0
    """Slope of the soft safety (1/units of the margins)."""
    reward_weight: float = 0.1
    """Weight of the clipped reward next to the soft safety in the objective (module doc)."""
    discount: float = 0.9
    """Discount of later steps in the objective."""
    infeasible_log_safety: float = -10.0
    """Log soft safety of a step whose equations have no solution."""
    average: float = 0.9
    """Decay of the running average of the weights that is evaluated and kept (0: the
    current weights). Averaging smooths the step-to-step noise of the fresh batches."""
    anchor_weight: float = 0.0
    """Weight of a pull towards the starting policy's mean actions (0: none). The penalty
    is the mean over the batch's start states from which the starting policy survives
    ``anchor_steps`` steps of the squared action change, each axis in units of its action
    box width: the refinement then fixes the states the starting policy fails from and
    keeps its actions (and so its nominal gait) where it already walks."""
    anchor_steps: int = 10
    """Steps the starting policy must survive from a start state for the anchor to hold
    there."""
    seed: int = 0
    """Seed of the start-state draws."""

    def __post_init__(self):
        v.check_fields(
            self,
            [
                v.integer(self, "iterations", 0),
                v.integer(self, "batch", 1),
                v.integer(self, "horizon", 1),
                *v.positive(self, "learning_rate", "adam_eps", "sharpness"),
                v.integer(self, "anchor_steps", 1),
                *v.non_negative(self, "clip_norm", "margin", "reward_weight", "anchor_weight"),
                ("average", 0.0 <= self.average < 1.0, "in [0, 1)"),
                *v.unit_interval(self, "discount"),
                (
                    "infeasible_log_safety",
                    self.infeasible_log_safety <= 0,
                    "<= 0 (a log probability)",
                ),
            ],
        )


def log_soft_safety(plan, psp: PSPParams, cfg: RefineConfig):
    """Log of the soft probability that one planned step is safe (see the module docstring)."""
    margins = safety_margins(plan, psp)
    log_safe = jnp.sum(jax.nn.log_sigmoid(cfg.sharpness * (margins - cfg.margin)), axis=-1)
    return jnp.where(plan.valid.next_state, log_safe, cfg.infeasible_log_safety)


def rollout_objective(policy, state, psp: PSPParams, cfg: RefineConfig):
    """``J`` for one apex state ``(3,)`` under ``policy`` (higher is better)."""
    # Unrolled: a lax.scan over the few steps compiles no faster and runs slower
    # (docs/architecture.md, measured choices).
    total, log_survival = 0.0, 0.0
    alive, scale = jnp.ones((), state.dtype), 1.0
    for _ in range(cfg.horizon):
        action = policy(state)
        plan = plan_step(state, action, psp)
        log_survival = log_survival + log_soft_safety(plan, psp, cfg)
        reward = jnp.clip(smooth_reward(plan, action, psp), -10.0, 0.0)
        total = total + scale * (jnp.exp(log_survival) + cfg.reward_weight * alive * reward)
        alive = alive * jax.lax.stop_gradient((~plan.terminal).astype(state.dtype))
        # Past an unsolvable step the next state is a placeholder: stay where we are.
        state = jnp.where(plan.valid.next_state, plan.next_state, state)
        scale = scale * cfg.discount
    return total


def _mean_weights(params: pol.ActorCriticParams):
    return params.table[..., pol.MEAN], params.bias[pol.MEAN]


def _with_mean_weights(params: pol.ActorCriticParams, weights) -> pol.ActorCriticParams:
    table, bias = weights
    return params.replace(
        table=params.table.at[..., pol.MEAN].set(table),
        bias=params.bias.at[pol.MEAN].set(bias),
    )


def make_refine_step(
    params: pol.ActorCriticParams,
    grid,
    psp: PSPParams,
    cfg: RefineConfig = RefineConfig(),
    starts: StartStates = StartStates(),
):
    """``(init_state, step)``: ``step(weights, opt_state, key) -> (weights, opt_state,
    objective)`` is one jitted Adam step on the mean weights; :func:`refined_params` puts
    them back into ``params``."""
    optimizer = optax.adam(cfg.learning_rate, eps=cfg.adam_eps)
    if cfg.clip_norm > 0:
        optimizer = optax.chain(optax.clip_by_global_norm(cfg.clip_norm), optimizer)

    anchor = mean_weights_policy(*_mean_weights(params), grid, psp)
    width = jnp.asarray(psp.action_high) - jnp.asarray(psp.action_low)

    def objective(weights, key):
        policy = mean_weights_policy(*weights, grid, psp)
        s0 = uniform_states(key, cfg.batch, starts).astype(weights[0].dtype)
        total = jnp.mean(jax.vmap(lambda s: rollout_objective(policy, s, psp, cfg))(s0))
        if cfg.anchor_weight == 0:
            return total
        held = steps_survived(anchor, s0, psp, cfg.anchor_steps) == cfg.anchor_steps
        change = (jax.vmap(policy)(s0) - jax.vmap(anchor)(s0)) / width.astype(s0.dtype)
        penalty = jnp.mean(jnp.where(held, jnp.sum(change**2, axis=-1), 0.0))
        return total - cfg.anchor_weight * penalty

    @functools.partial(jax.jit, compiler_options=cpu_compiler_options())
    def step(weights, opt_state, key):
        value, grad = jax.value_and_grad(objective)(weights, key)
        # Ascent: optax minimises.
        updates, opt_state = optimizer.update(jax.tree.map(jnp.negative, grad), opt_state)
        return optax.apply_updates(weights, updates), opt_state, value

    weights = _mean_weights(params)
    return (weights, optimizer.init(weights)), step


@jax.jit
def _running_average(averaged, weights, decay):
    return jax.tree.map(lambda a, w: decay * a + (1.0 - decay) * w, averaged, weights)


def refined_params(params: pol.ActorCriticParams, weights) -> pol.ActorCriticParams:
    """``params`` with the refined mean weights."""
    return _with_mean_weights(params, weights)


@dataclasses.dataclass
class RefineResult:
    best_params: pol.ActorCriticParams
    """The weights with the best evaluated basin (the starting ones if nothing beat them)."""
    best: dict | None
    """The kept weights' evaluation (``{"basin": ...}``; None without an evaluator)."""
    start: dict | None
    """The starting weights' evaluation."""
    history: list[dict]
    """One row per refinement step (objective, evaluations)."""
    compile_seconds: float
    """Wall time of the first step, compile included (s)."""
    train_seconds: float
    """Wall time of the steps after the first (compile excluded), evaluation excluded."""
    eval_seconds: float
    """Wall time of the evaluations (s)."""


def refine(
    params: pol.ActorCriticParams,
    grid,
    psp: PSPParams,
    cfg: RefineConfig = RefineConfig(),
    starts: StartStates = StartStates(),
    evaluate=None,
    every: int = 25,
    progress: bool = True,
    first_iteration: int = 0,
    wall_offset: float = 0.0,
) -> RefineResult:
    """Run ``cfg.iterations`` refinement steps from ``params``.

    ``evaluate(params) -> dict`` of basins (``"basin"``, and ``"steering_basin"`` when
    training steers; e.g. the training evaluator) is called on the starting weights and
    every ``every`` steps on the running average of the weights (``cfg.average``); the
    weights with the best mean of its values are kept, as in training. History rows continue
    the training history's ``iteration`` and ``wall_s`` from ``first_iteration`` and
    ``wall_offset``, and carry ``stage = "refine"``.
    """
    (weights, opt_state), step = make_refine_step(params, grid, psp, cfg, starts)
    averaged = weights
    base_key = jax.random.key(cfg.seed)
    history: list[dict] = []
    compile_s = train_s = eval_s = 0.0
    t_run = time.perf_counter()

    def evaluated(candidate):
        nonlocal eval_s
        t0 = time.perf_counter()
        basins = {k: float(v) for k, v in evaluate(candidate).items()}
        eval_s += time.perf_counter() - t0
        return basins, sum(basins.values()) / len(basins)

    best_params, best, best_score = params, None, None
    if evaluate is not None:
        best, best_score = evaluated(params)
    start = best
    bar = tqdm(total=cfg.iterations, desc="refine", unit="it", disable=not progress)
    for i in range(cfg.iterations):
        t0 = time.perf_counter()
        weights, opt_state, value = step(weights, opt_state, jax.random.fold_in(base_key, i))
        averaged = _running_average(averaged, weights, cfg.average)
        value = float(value)  # waits for the step
        dt = time.perf_counter() - t0
        if i == 0:
            compile_s = dt
        else:
            train_s += dt
        row = {
            "iteration": first_iteration + i + 1,
            "wall_s": wall_offset + time.perf_counter() - t_run,
            "stage": "refine",
            "objective": value,
        }
        if not math.isfinite(value):
            history.append(row)
            break
        last = i == cfg.iterations - 1
        if evaluate is not None and every and ((i + 1) % every == 0 or last):
            candidate = refined_params(params, averaged)
            basins, score = evaluated(candidate)
            row.update(basins)
            if score > best_score:
                best, best_score, best_params = basins, score, candidate
        history.append(row)
        bar.set_postfix(
            objective=f"{value:.3f}",
            basin=f"{best['basin']:.3f}" if best is not None else "-",
        )
        bar.update(1)
    bar.close()
    if evaluate is None:
        best_params = refined_params(params, averaged)
    return RefineResult(
        best_params=best_params,
        best=best,
        start=start,
        history=history,
        compile_seconds=compile_s,
        train_seconds=train_s,
        eval_seconds=eval_s,
    )
