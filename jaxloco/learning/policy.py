"""The RBF actor-critic network: a value and a Gaussian policy truncated to the action box.

Paper: Section II-B, Eq. 1-2, Fig. 5, and the authors' code. One weight table
with 7 outputs over the local RBF features (:mod:`jaxloco.learning.rbf`):

- output 0: the value ``v(s) = w . phi(s)``;
- outputs 1-3: the action means ``mu_k = theta_k . phi(s)``;
- outputs 4-6: the log spreads; ``sigma_k = exp(theta_{3+k} . phi(s))`` is the standard
  deviation of the normal distribution that is truncated to the action box (Eq. 2).
  (The authors' code sampled with it as a variance but differentiated it as a standard
  deviation; here it is a standard deviation in both.)
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct
from jax.scipy.special import log_ndtr

from jaxloco.learning import rbf

VALUE, MEAN, LOG_SPREAD = slice(0, 1), slice(1, 4), slice(4, 7)
NUM_OUTPUTS = 7
_HALF_LOG_2PI = 0.9189385332046727


@struct.dataclass
class ActorCriticParams:
    """Learned weights: the padded RBF table ``(*table_shape, 7)`` and the bias ``(7,)``."""

    table: jax.Array
    """``(*table_shape, 7)`` RBF weights: the policy's 3 means and 3 log-spreads and the value, per
    centre (padding cells zero)."""
    bias: jax.Array
    """(7,) the same channels' biases."""


def init_params(key, grid: rbf.RBFGrid, mean_bias=(0.3, 0.2, 0.0), init_scale=0.01, dtype=None):
    """The paper's initialisation: weights ``init_scale * U(0, 1)``, mean biases given.

    Padding cells of the table are zero (they never contribute or learn).
    """
    dtype = dtype or jnp.zeros(()).dtype
    k_table, k_bias = jax.random.split(key)
    full = init_scale * jax.random.uniform(k_table, (*grid.counts, NUM_OUTPUTS), dtype)
    r = grid.radius
    table = jnp.pad(full, ((r, r), (r, r), (r, r), (0, 0)))
    bias = init_scale * jax.random.uniform(k_bias, (NUM_OUTPUTS,), dtype)
    bias = bias.at[MEAN].set(jnp.asarray(mean_bias, dtype))
    return ActorCriticParams(table, bias)


# Numerical guards, far from any useful policy (the action box is 0.34-0.5 wide): spreads
# in [1e-3, 2] (log-spreads clipped), and for sampling and scoring a mean at most half a
# box width outside the box. Beyond that a truncated normal is all but a point mass or an
# exponential at the bound, its score stops pointing anywhere useful, and float32
# overflows. Updates still act on the raw weights, so a mean outside can come back.
LOG_SPREAD_MIN, LOG_SPREAD_MAX = -6.907755, 0.693147


def network_outputs(params: ActorCriticParams, features: rbf.LocalFeatures):
    """``(value, mean (3,), log_spread (3,))`` of one state."""
    out = rbf.evaluate(params.table, params.bias, features)
    return out[0], out[MEAN], jnp.clip(out[LOG_SPREAD], LOG_SPREAD_MIN, LOG_SPREAD_MAX)


def sampling_mean(mean, low, high):
    """The mean used for sampling and scoring: within half a box width of the box."""
    margin = 0.5 * (high - low)
    return jnp.clip(mean, low - margin, high + margin)


def log_normaliser(lower, upper):
    """``log(Phi(upper) - Phi(lower))`` for standardised bounds ``lower < upper``.

    Both bounds are first reflected into the lower tail when they lie in the upper one
    (``Phi(u) - Phi(l) = Phi(-l) - Phi(-u)``); then ``log Phi(u) + log1p(-Phi(l)/Phi(u))``
    is accurate everywhere, and its gradient is finite far into the tails.
    """
    flip = lower > 0.0
    lo = jnp.where(flip, -upper, lower)
    hi = jnp.where(flip, -lower, upper)
    log_hi = log_ndtr(hi)
    return log_hi + jnp.log1p(-jnp.exp(log_ndtr(lo) - log_hi))


def log_prob(action, mean, log_spread, low, high):
    """Log density of ``action`` under the truncated normals (summed over the 3 actions)."""
    spread = jnp.exp(log_spread)
    z = (action - mean) / spread
    lower, upper = (low - mean) / spread, (high - mean) / spread
    per_action = -0.5 * z**2 - log_spread - _HALF_LOG_2PI - log_normaliser(lower, upper)
    return jnp.sum(per_action, axis=-1)


def score(action, mean, log_spread, low, high):
    """Gradient of :func:`log_prob` w.r.t. ``(mean, log_spread)``: two (3,) arrays.

    The policy weights' gradient is then ``outer(phi(s), [d_mean, d_log_spread])``.
    """
    return jax.grad(log_prob, argnums=(1, 2))(action, mean, log_spread, low, high)


def sample(key, mean, log_spread, low, high):
    """One action from the truncated normals (Eq. 2)."""
    spread = jnp.exp(log_spread)
    lower, upper = (low - mean) / spread, (high - mean) / spread
    z = jax.random.truncated_normal(key, lower, upper, shape=mean.shape, dtype=mean.dtype)
    # Far in a tail the sampler can return a non-finite value; use the nearest bound there.
    z = jnp.where(jnp.isfinite(z), z, jnp.clip(0.0, lower, upper))
    return jnp.clip(mean + spread * z, low, high)


def mean_action(mean, low, high):
    """The deterministic policy: the mean, clipped to the action box."""
    return jnp.clip(mean, low, high)
