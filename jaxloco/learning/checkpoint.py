"""Saving, loading and using trained RL-PSP planners.

A checkpoint is a folder:

- ``weights.npz``: the learned table over the grid's centres ``(18, 30, 56, 7)`` (value,
  3 means, 3 log-spreads) and the bias ``(7,)``, float32, compressed;
- ``config.json``: the :class:`~jaxloco.learning.training.TrainConfig` it was trained with,
  and facts about the run (iteration, basin, timings);
- ``train_state.msgpack`` (optional): the full training state, to resume training.

The checkpoint kinds' files and the shipped policies (:data:`SHIPPED_POLICIES`) are named
here; :func:`load_learned_planner` loads this kind. Every kind loads through one
dispatcher, :func:`jaxloco.learning.loading.load_planner`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization, struct

from jaxloco.config import to_params
from jaxloco.learning import policy as pol
from jaxloco.learning import rbf
from jaxloco.learning.actor_critic import (
    ActorCriticConfig,
    TrainState,
    init_train_state,
)
from jaxloco.learning.evaluation import mean_policy, over_states
from jaxloco.learning.refine import RefineConfig
from jaxloco.learning.starts import EpisodeTurns, StartStates
from jaxloco.learning.training import EvalConfig, TrainConfig
from jaxloco.planner import PSPParams
from jaxloco.runtime import assets_dir  # noqa: F401 (re-exported)

DEFAULT_POLICY = "policies/rl_psp_fallback"
SHIPPED_POLICIES = {
    "default": DEFAULT_POLICY,
    "algorithm1": "policies/rl_psp",
    "refined": "policies/rl_psp_refined",
    "g1": "policies/g1",
    "apollo": "policies/apollo",
}
"""Policies in ``assets/``. ``algorithm1``: Algorithm 1 alone, as the paper (``jaxloco
train-planner refine.iterations=0 actor_critic.max_iterations=600``). ``refined``: the same
weights refined through the planner (600 + 300 steps at horizon 4): a larger survival
basin, but alone it recovers fewer pushes on the full robot. ``default``, which the walking
controller uses: ``algorithm1`` with ``refined`` as its fallback
(:mod:`~jaxloco.learning.fallback`): the survival basin of ``refined``, and Algorithm 1's
actions wherever its look-ahead is safe (docs/learning.md). ``g1``, ``apollo``: ``default``
at those robots' sizes (:mod:`~jaxloco.learning.scaled`), their walking controllers'
defaults."""
FORMAT_VERSION = 1
PPO_PARAMS_FILE = "ppo_params.msgpack"
"""The file that marks a checkpoint of :mod:`jaxloco.learning.ppo` (Brax's PPO)."""
FALLBACK_FILE = "fallback.json"
"""The file that marks a checkpoint of :mod:`jaxloco.learning.fallback`."""
SCALED_FILE = "scaled.json"
"""The file that marks a checkpoint of :mod:`jaxloco.learning.scaled`."""


def save_checkpoint(
    path, params: pol.ActorCriticParams, config: TrainConfig, info=None, train_state=None
) -> Path:
    """Write a checkpoint folder (created if needed); returns its path."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    table = np.asarray(rbf.unpad(config.grid, params.table), np.float32)
    np.savez_compressed(path / "weights.npz", table=table, bias=np.asarray(params.bias, np.float32))
    meta = {
        "format_version": FORMAT_VERSION,
        "config": dataclasses.asdict(config),
        "info": info or {},
    }
    (path / "config.json").write_text(json.dumps(meta, indent=2, default=_json_default) + "\n")
    if train_state is not None:
        (path / "train_state.msgpack").write_bytes(serialization.to_bytes(train_state))
    return path


def load_checkpoint_config(path) -> tuple[TrainConfig, dict]:
    """The :class:`TrainConfig` and run info stored in a checkpoint folder."""
    meta = json.loads((Path(path) / "config.json").read_text())
    if meta.get("format_version") != FORMAT_VERSION:
        raise ValueError(
            f"{path}: checkpoint format {meta.get('format_version')!r}, expected {FORMAT_VERSION}"
        )
    c = meta["config"]
    config = TrainConfig(
        actor_critic=to_params(ActorCriticConfig, c["actor_critic"]),
        grid=to_params(rbf.RBFGrid, c["grid"]),
        starts=to_params(StartStates, c["starts"]),
        planner=to_params(PSPParams, c["planner"]),
        evaluation=to_params(EvalConfig, c["evaluation"]),
        # Checkpoints from before steering training walked straight.
        turns=to_params(EpisodeTurns, c.get("turns", {})),
        # Checkpoints from before refinement were Algorithm 1 alone.
        refine=to_params(RefineConfig, c.get("refine", {"iterations": 0})),
    )
    return config, meta.get("info", {})


def load_params(path, config: TrainConfig, dtype=jnp.float32) -> pol.ActorCriticParams:
    """The weights of a checkpoint, as the padded table the network evaluates."""
    path = Path(path)
    with np.load(path / "weights.npz") as data:
        table, bias = data["table"], data["bias"]
    expected = (*config.grid.counts, pol.NUM_OUTPUTS)
    if table.shape != expected:
        raise ValueError(f"{path}: weight table has shape {table.shape}, expected {expected}")
    r = config.grid.radius
    padded = np.pad(table, ((r, r), (r, r), (r, r), (0, 0)))
    return pol.ActorCriticParams(jnp.asarray(padded, dtype), jnp.asarray(bias, dtype))


def load_train_state(path, config: TrainConfig) -> TrainState:
    """The full training state saved with a checkpoint (to resume training)."""
    path = Path(path) / "train_state.msgpack"
    if not path.exists():
        raise FileNotFoundError(f"{path} not found: this checkpoint cannot resume training")
    template = init_train_state(config.actor_critic, config.grid)
    return serialization.from_bytes(template, path.read_bytes())


@struct.dataclass
class LearnedPlanner:
    """A trained RL-PSP planner: the deterministic step policy and the learned value.

    A pytree (weights are leaves, the grid and planner parameters static), so it can be
    passed into ``jit``-ed functions.
    """

    params: pol.ActorCriticParams
    """The actor's and critic's weights (leaves)."""
    grid: rbf.RBFGrid = struct.field(pytree_node=False)
    """The RBF grid the weights are laid on (static)."""
    psp: PSPParams = struct.field(pytree_node=False)
    """The planner's parameters: its LIPM, action box and reward (static)."""

    def policy(self, state):
        """The deterministic policy for one apex state ``(3,) -> (3,)`` (for plan_steps)."""
        return mean_policy(self.params, self.grid, self.psp)(state)

    def mean_action(self, state):
        """Mean actions for apex states ``(..., 3)`` (jittable, batched over leading axes)."""
        return over_states(self.policy, state)

    def value(self, state):
        """Learned value ``v(s)`` for apex states ``(..., 3)``: the paper's walking risk."""

        def one(s):
            table, bias = self.params.table[..., pol.VALUE], self.params.bias[pol.VALUE]
            return rbf.evaluate(table, bias, rbf.local_features(self.grid, s))[0]

        return over_states(one, state)

    def spread(self, state):
        """Policy spreads ``(..., 3)`` (how sure the policy is)."""

        def one(s):
            _, _, log_spread = pol.network_outputs(self.params, rbf.local_features(self.grid, s))
            return jnp.exp(log_spread)

        return over_states(one, state)


def shipped_path(shipped: str = "default") -> Path:
    """The folder of the policy shipped with jaxloco named ``shipped`` (a key of
    :data:`SHIPPED_POLICIES`)."""
    if shipped not in SHIPPED_POLICIES:
        raise ValueError(
            f"load_planner: shipped must be one of {sorted(SHIPPED_POLICIES)}; got {shipped!r}"
        )
    return assets_dir() / SHIPPED_POLICIES[shipped]


def load_learned_planner(path) -> LearnedPlanner:
    """The :class:`LearnedPlanner` of an RL-PSP checkpoint folder (``weights.npz`` and
    ``config.json``)."""
    path = Path(path)
    if not (path / "weights.npz").exists():
        raise FileNotFoundError(
            f"no planner checkpoint at {path} (expected weights.npz or {PPO_PARAMS_FILE}, "
            "and config.json); train one with `jaxloco train-planner`"
        )
    config, _ = load_checkpoint_config(path)
    return LearnedPlanner(load_params(path, config), config.grid, config.planner)


def files_digest(path) -> str:
    """A short SHA-256 of the files a leaf checkpoint (RL-PSP or PPO) is loaded from."""
    path = Path(path)
    h = hashlib.sha256()
    for name in ("config.json", "weights.npz", PPO_PARAMS_FILE):
        if (path / name).exists():
            h.update(name.encode())
            h.update((path / name).read_bytes())
    if h.digest() == hashlib.sha256().digest():
        raise FileNotFoundError(f"no planner checkpoint at {path}")
    return h.hexdigest()[:16]


def _json_default(obj):
    if isinstance(obj, (np.generic, jax.Array, np.ndarray)):
        return np.asarray(obj).tolist()
    raise TypeError(f"cannot serialise {type(obj).__name__}")
