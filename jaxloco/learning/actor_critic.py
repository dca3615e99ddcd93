"""Algorithm 1 (actor-critic with eligibility traces), batched over parallel episodes.

Paper Section II-B, Algorithm 1. Per step of an episode::

    delta  = R + gamma v(s') - v(s)          (v(s') = 0 when s' is terminal)
    e_w    = lambda_w e_w + I grad_w v(s)
    e_th   = lambda_th e_th + I grad_th log pi(a | s)
    w     += beta delta e_w ;  theta += alpha delta e_th ;  I *= gamma

(The traces decay by lambda as the paper writes them; Sutton and Barto decay by
gamma * lambda.)

**Batched form.** Per-episode traces are as large as the weights (30,241 x 7), far too large
to keep for thousands of parallel episodes. With the weights held fixed during an episode,
the episode's summed update has a forward-view form that needs no trace at all::

    sum_t delta_t e_t = sum_t delta_t sum_{j<=t} lambda^{t-j} I_j g_j
                      = sum_j I_j g_j A_j,   A_j = sum_{t>=j} lambda^{t-j} delta_t

where ``g_j`` is the (sparse) gradient at step j and ``A_j = delta_j + lambda A_{j+1}`` is a
reverse scan of scalars. Each step's sparse gradient is scaled by one scalar and
scatter-added into the weights. So one iteration runs ``episodes_per_iteration`` episodes
in parallel with the current weights, then applies the sum of their updates: exactly
Algorithm 1 with updates applied at the end of each episode (offline), for that many
episodes. It differs from the online version (weights changing inside an episode) by
O(alpha^2) per episode (tests check both statements on a small problem). Episodes end at a
terminal step or after ``max_episode_steps`` (then ``v(s')`` is bootstrapped).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import optax
from flax import struct

from jaxloco import validation as v
from jaxloco.learning import policy as pol
from jaxloco.learning import rbf
from jaxloco.learning.starts import EpisodeTurns, StartStates, episode_turns, training_starts
from jaxloco.planner import PSPParams, lipm, plan_step
from jaxloco.planner.steering import turn_local_frame
from jaxloco.runtime import cpu_compiler_options

OPTIMIZERS = ("sgd", "adam")


@dataclasses.dataclass(frozen=True)
class ActorCriticConfig:
    """Hyper-parameters of Algorithm 1 (defaults: the paper's authors') and of batching."""

    gamma: float = 0.9
    """Discount factor of the return (in [0, 1])."""
    alpha: float = 3e-5
    """Actor (policy) step size."""
    beta: float = 3e-5
    """Critic (value) step size."""
    lambda_theta: float = 0.88
    """Eligibility-trace decay of the actor (in [0, 1])."""
    lambda_w: float = 0.88
    """Eligibility-trace decay of the critic (in [0, 1])."""
    init_scale: float = 0.01
    """Initial weights are init_scale * U(0, 1)."""
    mean_bias: tuple[float, float, float] = (0.3, 0.2, 0.0)
    """Bias of the policy mean per action ``(p_x, xd_apex_next, yd_apex_next)`` (m, m/s, m/s)."""
    initial_spread: float = 0.0
    """If > 0, start every policy spread at this value (log-spread weights 0, bias
    log(initial_spread)) and every mean at mean_bias (mean weights 0), instead of the
    paper's exp(0.01 U(0,1) . phi) ~ 1.1, which makes the first actions nearly uniform."""
    episodes_per_iteration: int = 1024
    """Episodes run side by side (vmapped) per update."""
    max_episode_steps: int = 20
    """Steps after which an episode is cut (and bootstrapped)."""
    max_iterations: int = 300
    """Updates at most (0: none, e.g. refinement from the initial weights)."""
    spread_target: float = 0.07
    """Stop when the mean spread of every action over the visited states is below this."""
    optimizer: str = "sgd"
    """``sgd``: Algorithm 1 as written (steps alpha, beta on the summed episode updates).
    ``adam``: the same update direction through Adam (optax), steps alpha, beta per channel;
    robust to many episodes updating the same weights in one batch."""
    normalize: str = "none"
    """``none``: the summed episode updates (Algorithm 1). ``visits``: each weight's sum is
    divided by ``1 + sum phi`` over the batch, i.e. averaged over the samples that touched
    it, so a step moves a cell towards the mean of its own evidence (stable with many
    episodes per batch; alpha, beta become fractions)."""
    spread_step_scale: float = 1.0
    """The log-spread channels step with ``spread_step_scale * alpha`` (1 in Algorithm 1).
    Spreads should move more cautiously than means: one unlucky batch can collapse them."""
    natural_gradient: bool = False
    """Precondition the actor's direction by the inverse Fisher information of a normal
    distribution (d/d mean x sigma^2, d/d log-spread x 1/2): the mean then moves in action
    units, by (a - mean) x advantage, whatever the spread. Plain gradient when False."""
    normalize_advantage: bool = False
    """Centre and scale the actor's forward-view TD sums A^theta by their mean and standard
    deviation over the batch, and clip them to +-3 (the critic's are left as they are):
    bounded actor steps whatever the reward scale and however wrong the critic still is."""
    advantage_std_floor: float = 0.0
    """With normalize_advantage: divide by max(std, this floor), so that once the TD errors
    shrink to noise they are not amplified back to unit size."""
    seed: int = 0
    """Seed of the initial weights and of the episodes' draws."""

    def __post_init__(self):
        v.check_fields(
            self,
            [
                *v.positive(
                    self, "alpha", "beta", "init_scale", "spread_target", "spread_step_scale"
                ),
                *v.unit_interval(self, "gamma", "lambda_theta", "lambda_w"),
                v.one_of(self, "normalize", ("none", "visits")),
                v.one_of(self, "optimizer", OPTIMIZERS),
                v.integer(self, "episodes_per_iteration", 1),
                v.integer(self, "max_episode_steps", 1),
                # 0: no Algorithm 1 (e.g. refinement from the initial weights).
                v.integer(self, "max_iterations", 0),
            ],
        )


@struct.dataclass
class Rollout:
    """What one batch of episodes leaves for the update; leading axes (steps, episodes)."""

    features: rbf.LocalFeatures
    """The RBF features of each visited state."""
    state: jax.Array
    """(steps, episodes, 3) apex states."""
    action: jax.Array
    """(steps, episodes, 3) actions taken."""
    value: jax.Array
    """(steps, episodes) the critic's ``v(state)``."""
    d_mean: jax.Array
    """(steps, episodes, 3) d log pi / d mean at the action taken."""
    d_log_spread: jax.Array
    """(steps, episodes, 3) d log pi / d log-spread at the action taken."""
    log_spread: jax.Array
    """(steps, episodes, 3) the policy's log-spread at the state."""
    reward: jax.Array
    """(steps, episodes) the step's reward (Eq. 3)."""
    terminal: jax.Array
    """(steps, episodes) bool, the step ended the episode (Eq. 4)."""
    active: jax.Array
    """True where the episode is still running at this step (the step counts)."""
    final_state: jax.Array
    """(episodes, 3) state after the last step."""
    final_value: jax.Array
    """v(final_state), for bootstrapping episodes cut by the step cap."""


@struct.dataclass
class IterationStats:
    mean_return: jax.Array
    """() mean discounted return of the batch's episodes."""
    survival: jax.Array
    """Fraction of episodes still alive after max_episode_steps."""
    mean_length: jax.Array
    """() mean episode length (steps)."""
    spread: jax.Array
    """(3,) mean policy spread over the visited states."""
    mean_abs_td: jax.Array
    """() mean absolute TD error over the steps that counted."""


def rollout(
    params, key, starts, grid: rbf.RBFGrid, psp: PSPParams, num_steps: int, turns=None
) -> Rollout:
    """Run episodes from ``starts (B, 3)`` with the stochastic policy, weights fixed.

    ``turns``: optional ``(B,)`` heading change per step (rad) of each episode. After each
    step the next frame is turned and the state carried to its apex, as
    :func:`~jaxloco.planner.plan_steps` steers; a step is then also terminal when its switch
    falls before the re-projected start (``SWITCH_IN_PAST``) or the turned state has no apex.
    """
    low = jnp.asarray(psp.action_low, starts.dtype)
    high = jnp.asarray(psp.action_high, starts.dtype)
    batch = starts.shape[0]
    if turns is not None:
        turns = jnp.asarray(turns, starts.dtype)
        if turns.shape != (batch,):
            raise ValueError(f"turns must have shape ({batch},); got {turns.shape}")

    def step(carry, key_t):
        state, tau, sigma, active = carry
        feats = jax.vmap(lambda s: rbf.local_features(grid, s))(state)
        value, mean, log_spread = jax.vmap(pol.network_outputs, in_axes=(None, 0))(params, feats)
        mean = pol.sampling_mean(mean, low, high)
        keys = jax.random.split(key_t, state.shape[0])
        action = jax.vmap(pol.sample, in_axes=(0, 0, 0, None, None))(
            keys, mean, log_spread, low, high
        )
        d_mean, d_log_spread = jax.vmap(pol.score, in_axes=(0, 0, 0, None, None))(
            action, mean, log_spread, low, high
        )
        # A sample whose score is not finite (float32 far in a tail) teaches nothing.
        finite = jnp.all(jnp.isfinite(d_mean) & jnp.isfinite(d_log_spread), axis=-1)
        d_mean = jnp.where(finite[:, None], d_mean, 0.0)
        d_log_spread = jnp.where(finite[:, None], d_log_spread, 0.0)
        plan = plan_step(state, action, psp)
        reward, terminal, next_apex = plan.reward, plan.terminal, plan.next_state
        next_tau = tau
        if turns is not None:
            next_apex, next_tau, apex_ok = _turned_apex(plan.next_state, -sigma, turns, psp)
            # As plan_steps: only the re-projection can put a safe switch in the past.
            in_past = (tau + plan.t_switch <= 0.0) & (plan.t_switch > psp.t_switch_min)
            failed = ~terminal & (in_past | ~apex_ok)
            reward = jnp.where(failed, jnp.asarray(psp.terminal_reward, reward.dtype), reward)
            terminal = terminal | failed
        out = dict(
            features=feats,
            state=state,
            action=action,
            value=value,
            d_mean=d_mean,
            d_log_spread=d_log_spread,
            log_spread=log_spread,
            reward=reward,
            terminal=terminal,
            active=active,
        )
        next_state = jnp.where(terminal[:, None], state, next_apex)
        next_tau = jnp.where(terminal, tau, next_tau)
        return (next_state, next_tau, -sigma, active & ~terminal), out

    zeros = jnp.zeros((batch,), starts.dtype)
    init = (starts, zeros, jnp.ones_like(zeros), jnp.ones(batch, bool))
    (last_state, *_), out = jax.lax.scan(step, init, jax.random.split(key, num_steps))
    last_feats = jax.vmap(lambda s: rbf.local_features(grid, s))(last_state)
    final_value = jax.vmap(pol.network_outputs, in_axes=(None, 0))(params, last_feats)[0]
    return Rollout(**out, final_state=last_state, final_value=final_value)


def _turned_apex(apex, next_sign, turns, psp: PSPParams):
    """The next apex state ``(B, 3)`` (in the next foot's frame) after turning that frame by
    ``turns``: ``(apex state of the turned frame, time to it from the step start, valid)``."""
    local = jnp.stack([jnp.zeros_like(apex[:, 0]), apex[:, 1], apex[:, 0], apex[:, 2]], -1)
    turned = turn_local_frame(local, next_sign, jnp.cos(turns), jnp.sin(turns))
    w = psp.omega
    tau, v_apex, growth, ok = lipm.apex_growth_of(turned[:, 0], turned[:, 1], 0.0, w)
    y_apex, yd_apex = lipm.propagate_by_growth(turned[:, 2], turned[:, 3], 0.0, w, growth)
    return jnp.stack([y_apex, v_apex, yd_apex], -1), tau, ok


def td_errors(ro: Rollout, gamma: float):
    """``delta_t`` per step (zero once an episode has ended), shape (steps, episodes)."""
    next_value = jnp.concatenate([ro.value[1:], ro.final_value[None]], axis=0)
    next_value = jnp.where(ro.terminal, 0.0, next_value)
    delta = ro.reward + gamma * next_value - ro.value
    return jnp.where(ro.active, delta, 0.0)


def update_direction(params, ro: Rollout, cfg: ActorCriticConfig):
    """The batch's summed forward-view update with unit step sizes (see the module doc).

    Returns ``(direction, delta)``: ``direction`` has the shape of ``params``; channel 0 is
    ``sum_j I_j A^w_j grad v`` and channels 1-6 are ``sum_j I_j A^theta_j grad log pi``.
    """
    delta = td_errors(ro, cfg.gamma)
    num_steps = delta.shape[0]
    discount = cfg.gamma ** jnp.arange(num_steps, dtype=delta.dtype)  # I_t

    actor_shift, actor_scale, clip_advantage = 0.0, 1.0, jnp.inf
    if cfg.normalize_advantage:
        # Forward-view sums A^theta for every step, to measure their spread over the batch.
        def accumulate(acc, t):
            acc = delta[t] + cfg.lambda_theta * acc
            return acc, acc

        _, adv = jax.lax.scan(accumulate, jnp.zeros_like(delta[0]), jnp.arange(num_steps)[::-1])
        active = ro.active[::-1]
        n_active = jnp.maximum(jnp.sum(active), 1)
        adv_mean = jnp.sum(jnp.where(active, adv, 0.0)) / n_active
        adv_var = jnp.sum(jnp.where(active, (adv - adv_mean) ** 2, 0.0)) / n_active
        adv_std = jnp.maximum(jnp.sqrt(adv_var), cfg.advantage_std_floor)
        actor_shift, actor_scale = adv_mean, 1.0 / (adv_std + 1e-6)
    clip_advantage = 3.0 if cfg.normalize_advantage else jnp.inf  # in standard deviations
    if cfg.natural_gradient:
        d_mean = ro.d_mean * jnp.exp(2.0 * ro.log_spread)
        # Clipped like the advantages below: one sample in a rarely visited cell (which
        # visit-averaging gives a full step) must not collapse or blow up a spread.
        d_log_spread = jnp.clip(0.5 * ro.d_log_spread, -2.0, 2.0)
    else:
        d_mean, d_log_spread = ro.d_mean, ro.d_log_spread

    def backward(carry, t):
        table, bias, acc_w, acc_th = carry
        acc_w = delta[t] + cfg.lambda_w * acc_w
        acc_th = delta[t] + cfg.lambda_theta * acc_th
        scale = jnp.where(ro.active[t], discount[t], 0.0)
        adv = jnp.clip(actor_scale * (acc_th - actor_shift), -clip_advantage, clip_advantage)
        coef = jnp.concatenate(
            [
                (scale * acc_w)[:, None],
                (scale * adv)[:, None] * d_mean[t],
                (scale * adv)[:, None] * d_log_spread[t],
                ro.active[t].astype(delta.dtype)[:, None],  # visit mass (last channel)
            ],
            axis=-1,
        )
        feats_t = jax.tree.map(lambda x: x[t], ro.features)
        table = rbf.scatter_add(table, feats_t, coef)
        bias = bias + jnp.sum(coef, axis=0)  # the bias feature is 1
        return (table, bias, acc_w, acc_th), None

    zeros = jnp.zeros(delta.shape[1], delta.dtype)
    channels = params.table.shape[-1] + 1
    init = (
        jnp.zeros((*params.table.shape[:-1], channels), delta.dtype),
        jnp.zeros((channels,), delta.dtype),
        zeros,
        zeros,
    )
    (table, bias, _, _), _ = jax.lax.scan(backward, init, jnp.arange(num_steps)[::-1])
    if cfg.normalize == "visits":
        table = table[..., :-1] / (1.0 + table[..., -1:])
        bias = bias[:-1] / (1.0 + bias[-1])
    else:
        table, bias = table[..., :-1], bias[:-1]
    return pol.ActorCriticParams(table=table, bias=bias), delta


def step_sizes(cfg: ActorCriticConfig):
    """Per-output step sizes: beta (value), alpha (means), spread_step_scale * alpha (spreads)."""
    return jnp.asarray([cfg.beta] + [cfg.alpha] * 3 + [cfg.spread_step_scale * cfg.alpha] * 3)


def make_optimizer(cfg: ActorCriticConfig) -> optax.GradientTransformation:
    """Ascent on the update direction, with step size beta (critic) and alpha (actor)."""
    lr = step_sizes(cfg)
    per_channel = optax.stateless(
        lambda updates, _params: jax.tree.map(lambda u: u * lr.astype(u.dtype), updates)
    )
    if cfg.optimizer == "sgd":
        return per_channel
    # Adam normalises each weight's step by its own update history.
    return optax.chain(optax.scale_by_adam(), per_channel)


def iteration_stats(ro: Rollout, delta) -> IterationStats:
    active = ro.active.astype(ro.reward.dtype)
    lengths = jnp.sum(active, axis=0)
    weight = active[..., None]
    spread = jnp.sum(jnp.exp(ro.log_spread) * weight, axis=(0, 1)) / jnp.maximum(
        jnp.sum(weight, axis=(0, 1)), 1.0
    )
    survived = ro.active[-1] & ~ro.terminal[-1]
    return IterationStats(
        mean_return=jnp.mean(jnp.sum(ro.reward * active, axis=0)),
        survival=jnp.mean(survived.astype(ro.reward.dtype)),
        mean_length=jnp.mean(lengths),
        spread=spread,
        mean_abs_td=jnp.sum(jnp.abs(delta)) / jnp.maximum(jnp.sum(active), 1.0),
    )


@struct.dataclass
class TrainState:
    params: pol.ActorCriticParams
    """The actor's and critic's weights."""
    opt_state: optax.OptState
    """The optimizer's state (optax)."""
    iteration: jax.Array
    """() int, updates done."""


def init_train_state(
    cfg: ActorCriticConfig, grid: rbf.RBFGrid = rbf.RBFGrid(), key=None, dtype=None
) -> TrainState:
    key = jax.random.key(cfg.seed) if key is None else key
    params = pol.init_params(key, grid, cfg.mean_bias, cfg.init_scale, dtype)
    if cfg.initial_spread > 0:
        # A narrow start needs the means to start exactly at mean_bias: the paper's random
        # table weights add ~0.08 (0.005 x sum(phi) = 15.7) to every mean.
        params = params.replace(
            table=params.table.at[..., pol.LOG_SPREAD].set(0.0).at[..., pol.MEAN].set(0.0),
            bias=params.bias.at[pol.LOG_SPREAD].set(jnp.log(cfg.initial_spread)),
        )
    return TrainState(params, make_optimizer(cfg).init(params), jnp.zeros((), jnp.int32))


def make_train_iteration(
    cfg: ActorCriticConfig,
    grid: rbf.RBFGrid = rbf.RBFGrid(),
    psp: PSPParams = PSPParams(),
    starts: StartStates = StartStates(),
    turns: EpisodeTurns = EpisodeTurns(),
):
    """A jitted ``(state, key) -> (state, stats)``: one batch of episodes and its update."""
    optimizer = make_optimizer(cfg)

    @functools.partial(jax.jit, compiler_options=cpu_compiler_options())
    def iteration(state: TrainState, key):
        k_start, k_roll = jax.random.split(key)
        s0 = training_starts(k_start, cfg.episodes_per_iteration, psp, starts)
        s0 = s0.astype(state.params.table.dtype)
        episode_turn = None
        if turns.enabled:  # a separate key stream: straight training draws what it always did
            k_turn = jax.random.fold_in(key, 1)
            episode_turn = episode_turns(k_turn, cfg.episodes_per_iteration, turns, s0.dtype)
        ro = rollout(state.params, k_roll, s0, grid, psp, cfg.max_episode_steps, episode_turn)
        direction, delta = update_direction(state.params, ro, cfg)
        updates, opt_state = optimizer.update(direction, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        new_state = TrainState(params, opt_state, state.iteration + 1)
        return new_state, iteration_stats(ro, delta)

    return iteration
