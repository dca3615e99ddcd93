"""A PPO baseline for the step policy: Brax's PPO trained on :class:`~.brax_env.StepEnv`.

Not in the paper: the yardstick a new step learner is compared against. Training is
``brax.training.agents.ppo.train`` as Brax ships it (tanh-squashed normal policy, GAE,
observation normalisation); this module gives it a config, a progress bar, the survival
basin of the deterministic policy at each of Brax's evaluations (on the same fixed draw
Algorithm 1's training evaluates on), and a planner with the interface of
:class:`~.checkpoint.LearnedPlanner` (``policy``, ``mean_action``, ``value``), which
:func:`~.checkpoint.load_planner` loads from a checkpoint folder.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from brax.training.acme import running_statistics, specs
from brax.training.agents.ppo import networks as ppo_networks
from brax.training.agents.ppo import train as brax_ppo
from flax import serialization, struct
from tqdm.auto import tqdm

from jaxloco import validation as v
from jaxloco.config import to_params
from jaxloco.learning.brax_env import StepEnv, box_action
from jaxloco.learning.checkpoint import PPO_PARAMS_FILE
from jaxloco.learning.evaluation import over_states, survival_basin
from jaxloco.learning.starts import StartStates
from jaxloco.planner import PSPParams


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """Brax PPO on the step task (names as ``brax.training.agents.ppo.train`` takes them)."""

    num_timesteps: int = 4_000_000
    """Environment steps (walking steps planned) over the whole run."""
    num_envs: int = 1024
    """Environments run side by side."""
    episode_length: int = 50
    """Steps per episode (the paper's 50)."""
    unroll_length: int = 10
    """Steps per environment between updates."""
    batch_size: int = 512
    """Unrolls per minibatch."""
    num_minibatches: int = 8
    """Minibatches per update."""
    num_updates_per_batch: int = 4
    """Passes over each batch."""
    learning_rate: float = 1e-3
    """Adam's step size."""
    entropy_cost: float = 1e-3
    """Weight of the policy's entropy bonus."""
    discounting: float = 0.9
    """The paper's gamma."""
    reward_scaling: float = 1.0
    """Factor on every reward before the update."""
    policy_hidden: tuple[int, ...] = (64, 64)
    """Hidden layer widths of the policy network."""
    value_hidden: tuple[int, ...] = (64, 64)
    """Hidden layer widths of the value network."""
    num_evals: int = 11
    """Evaluations (Brax's, and the survival basin) over the run, the first before training."""
    seed: int = 0
    """Seed of the networks' initial weights and of training."""
    pushed_fraction: float = 0.0
    """Share of episodes starting from pushed nominal states, as Algorithm 1 draws them
    (:class:`~.starts.StartStates`); 0: all from the box of Eq. 1."""
    basin_states: int = 2048
    """Box states of the survival-basin evaluation (the training evaluator's draw size)."""
    basin_steps: int = 50
    """Steps a basin start must survive to count."""
    basin_seed: int = 12345
    """The fixed draw, the same as :class:`~.training.EvalConfig`'s by default."""

    def __post_init__(self):
        for name in ("policy_hidden", "value_hidden"):
            object.__setattr__(self, name, tuple(int(n) for n in getattr(self, name)))
        v.check_fields(
            self,
            [
                v.integer(self, "num_timesteps", 1),
                v.integer(self, "num_envs", 1),
                v.integer(self, "episode_length", 1),
                v.integer(self, "unroll_length", 1),
                v.integer(self, "batch_size", 1),
                v.integer(self, "num_minibatches", 1),
                v.integer(self, "num_updates_per_batch", 1),
                v.integer(self, "num_evals", 1),
                v.integer(self, "basin_states", 1),
                v.integer(self, "basin_steps", 1),
                *v.positive(self, "learning_rate", "reward_scaling"),
                *v.non_negative(self, "entropy_cost"),
                *v.unit_interval(self, "discounting", "pushed_fraction"),
                (
                    "policy_hidden",
                    len(self.policy_hidden) > 0 and min(self.policy_hidden) > 0,
                    "a non-empty list of positive layer widths",
                ),
                (
                    "value_hidden",
                    len(self.value_hidden) > 0 and min(self.value_hidden) > 0,
                    "a non-empty list of positive layer widths",
                ),
                (
                    "num_envs",
                    (self.batch_size * self.num_minibatches) % self.num_envs == 0,
                    f"a divisor of batch_size * num_minibatches = "
                    f"{self.batch_size * self.num_minibatches} (Brax's PPO requires it)",
                ),
            ],
        )


def make_networks(config: PPOConfig) -> ppo_networks.PPONetworks:
    """Brax's PPO networks with this config's sizes and observation normalisation."""
    return ppo_networks.make_ppo_networks(
        observation_size=3,
        action_size=3,
        preprocess_observations_fn=running_statistics.normalize,
        policy_hidden_layer_sizes=config.policy_hidden,
        value_hidden_layer_sizes=config.value_hidden,
    )


@struct.dataclass
class PPOParams:
    """The three parameter trees Brax's PPO returns."""

    normalizer: running_statistics.RunningStatisticsState
    """Running mean and spread of the observations (Brax's normalizer)."""
    policy: dict
    """The policy network's weights (a flax parameter tree)."""
    value: dict
    """The value network's weights (a flax parameter tree)."""

    @classmethod
    def of(cls, params) -> PPOParams:
        """From Brax's ``(normalizer, policy, value)`` tuple."""
        normalizer, policy, value = params
        return cls(normalizer, policy, value)


def init_params(config: PPOConfig, key=None) -> PPOParams:
    """Untrained parameters of the config's networks (the template a checkpoint loads into)."""
    networks = make_networks(config)
    k_pol, k_val = jax.random.split(jax.random.key(config.seed) if key is None else key)
    normalizer = running_statistics.init_state(specs.Array((3,), jnp.dtype("float32")))
    return PPOParams(
        normalizer, networks.policy_network.init(k_pol), networks.value_network.init(k_val)
    )


@struct.dataclass
class PPOPlanner:
    """A PPO-trained step policy with :class:`~.checkpoint.LearnedPlanner`'s interface: the
    deterministic policy (the squashed mean, mapped onto the action box) and the learned
    value. A pytree (weights are leaves), so it can be passed into ``jit``-ed functions."""

    params: PPOParams
    """The trained weights (leaves)."""
    config: PPOConfig = struct.field(pytree_node=False)
    """The config it was trained with: its networks' shapes (static)."""
    psp: PSPParams = struct.field(pytree_node=False)
    """The planner's parameters: its action box (static)."""

    def policy(self, state):
        """The deterministic policy for one apex state ``(3,) -> (3,)`` (for plan_steps)."""
        networks = make_networks(self.config)
        logits = networks.policy_network.apply(
            self.params.normalizer, self.params.policy, state.astype(jnp.float32)
        )
        unit = networks.parametric_action_distribution.mode(logits)
        return box_action(unit, self.psp).astype(state.dtype)

    def mean_action(self, state):
        """Deterministic actions for apex states ``(..., 3)`` (jittable, batched)."""
        return over_states(self.policy, state)

    def value(self, state):
        """The learned value ``v(s)`` for apex states ``(..., 3)``."""
        networks = make_networks(self.config)

        def one(s):
            return networks.value_network.apply(
                self.params.normalizer, self.params.value, s.astype(jnp.float32)
            )

        return over_states(one, state)


@dataclasses.dataclass
class PPOResult:
    planner: PPOPlanner
    """The evaluated policy with the best survival basin (the final one if it is best)."""
    best_basin: float
    """Survival basin of ``planner`` (share of box starts that survive ``basin_steps``)."""
    history: list[dict]
    """One row per evaluation: ``env_steps``, ``wall_s`` (since the start, compile
    included), ``basin``, and Brax's ``eval/episode_reward``."""
    train_seconds: float
    """Wall time of the whole run, compile and evaluations included."""


def train_ppo(
    config: PPOConfig = PPOConfig(),
    psp: PSPParams = PSPParams(),
    starts: StartStates = StartStates(),
    progress: bool = True,
) -> PPOResult:
    """Train the baseline (see the module docstring) on the step task of ``psp``, episodes
    starting as ``starts`` draws them with ``config.pushed_fraction``; progress bar over
    env steps."""
    starts = dataclasses.replace(starts, pushed_fraction=config.pushed_fraction)
    env = StepEnv(psp, starts)
    basin_key = jax.random.key(config.basin_seed)

    @jax.jit
    def basin_of(params: PPOParams):
        planner = PPOPlanner(params, config, psp)
        return survival_basin(
            planner.policy, psp, basin_key, config.basin_states, config.basin_steps, starts
        )[0]

    history: list[dict] = []
    best: dict = {"basin": -1.0, "params": None}
    bar = tqdm(
        total=config.num_timesteps, desc="PPO", unit="step", unit_scale=True, disable=not progress
    )
    t0 = time.perf_counter()

    rewards: dict[int, float] = {}  # Brax's evaluation reward by env step

    def on_params(step, _make_policy, params):
        params = PPOParams.of(params)
        basin = float(basin_of(params))
        row = {"env_steps": int(step), "wall_s": time.perf_counter() - t0, "basin": basin}
        row["episode_reward"] = rewards.get(int(step))
        history.append(row)
        if basin > best["basin"]:
            best.update(basin=basin, params=params)
        bar.update(int(step) - bar.n)
        bar.set_postfix(basin=f"{best['basin']:.3f}")

    def on_metrics(step, metrics):
        # Brax reports its evaluation before the parameters at the start, after them later.
        reward = metrics.get("eval/episode_reward")
        if reward is None:
            return
        rewards[int(step)] = float(reward)
        if history and history[-1]["env_steps"] == int(step):
            history[-1]["episode_reward"] = float(reward)

    with _device_put_replicated():
        _run_brax_ppo(env, config, on_params, on_metrics)
    bar.close()
    return PPOResult(
        planner=PPOPlanner(best["params"], config, psp),
        best_basin=best["basin"],
        history=history,
        train_seconds=time.perf_counter() - t0,
    )


def _run_brax_ppo(env, config: PPOConfig, on_params, on_metrics) -> None:
    brax_ppo.train(
        environment=env,
        num_timesteps=config.num_timesteps,
        episode_length=config.episode_length,
        num_envs=config.num_envs,
        unroll_length=config.unroll_length,
        batch_size=config.batch_size,
        num_minibatches=config.num_minibatches,
        num_updates_per_batch=config.num_updates_per_batch,
        learning_rate=config.learning_rate,
        entropy_cost=config.entropy_cost,
        discounting=config.discounting,
        reward_scaling=config.reward_scaling,
        normalize_observations=True,
        num_evals=config.num_evals,
        seed=config.seed,
        network_factory=functools.partial(
            ppo_networks.make_ppo_networks,
            policy_hidden_layer_sizes=config.policy_hidden,
            value_hidden_layer_sizes=config.value_hidden,
        ),
        policy_params_fn=on_params,
        progress_fn=on_metrics,
    )


@contextlib.contextmanager
def _device_put_replicated():
    """Brax 0.14.2's PPO calls ``jax.device_put_replicated``, which JAX 0.10 removed: provide
    the replacement JAX's migration guide gives (``jax.device_put`` of the stacked copies,
    sharded over the devices) while a training runs, and take it away afterwards."""
    if hasattr(jax, "device_put_replicated"):  # a JAX that still has it
        yield
        return

    def device_put_replicated(tree, devices):
        mesh = jax.sharding.Mesh(np.asarray(devices), ("replica",))
        sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("replica"))
        stack = lambda x: jnp.stack([x] * len(devices))  # noqa: E731
        return jax.device_put(jax.tree.map(stack, tree), sharding)

    jax.device_put_replicated = device_put_replicated
    try:
        yield
    finally:
        del jax.device_put_replicated


CHECKPOINT_KIND = "ppo"
FORMAT_VERSION = 1


def save_ppo_checkpoint(path, planner: PPOPlanner, info=None) -> Path:
    """Write a checkpoint folder (created if needed): ``ppo_params.msgpack`` (the three
    parameter trees) and ``config.json`` (the PPO config, the planner parameters, ``info``);
    :func:`~.checkpoint.load_planner` reads it back. Returns its path."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    (path / PPO_PARAMS_FILE).write_bytes(serialization.to_bytes(planner.params))
    meta = {
        "format_version": FORMAT_VERSION,
        "kind": CHECKPOINT_KIND,
        "ppo": dataclasses.asdict(planner.config),
        "planner": dataclasses.asdict(planner.psp),
        "info": info or {},
    }
    (path / "config.json").write_text(json.dumps(meta, indent=2) + "\n")
    return path


def load_ppo_planner(path) -> PPOPlanner:
    """The planner saved by :func:`save_ppo_checkpoint` in ``path``."""
    path = Path(path)
    meta = json.loads((path / "config.json").read_text())
    if meta.get("kind") != CHECKPOINT_KIND or meta.get("format_version") != FORMAT_VERSION:
        raise ValueError(
            f"{path}: not a PPO checkpoint of format {FORMAT_VERSION} "
            f"(kind {meta.get('kind')!r}, format {meta.get('format_version')!r})"
        )
    config = to_params(PPOConfig, meta["ppo"])
    psp = to_params(PSPParams, meta["planner"])
    params = serialization.from_bytes(init_params(config), (path / PPO_PARAMS_FILE).read_bytes())
    return PPOPlanner(params, config, psp)
