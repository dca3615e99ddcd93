"""A small dense QP solver by ADMM, unrolled for a fixed number of iterations.

Solves ``min 1/2 x'Px + q'x  s.t.  l <= Ax <= u`` (rows with ``l = u`` are equalities)
with the OSQP splitting (Stellato et al., 2020): ``z = Ax`` with ``z`` projected on the box,
a scaled dual ``y``, over-relaxation ``alpha``, a per-row penalty ``rho`` (larger on
equalities). The linear system ``(P + sigma I + A' diag(rho) A) x = ...`` does not change
between iterations, so it is Cholesky-factored once per problem; the iterations are a
``lax.scan``, so the solver batches with ``vmap``, differentiates with ``grad`` and
warm-starts from a previous solution. It always returns finite numbers with its primal
and dual residuals; whether they are small enough is the caller's call.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class ADMMState:
    x: jax.Array
    z: jax.Array
    y: jax.Array


@struct.dataclass
class ADMMResult:
    x: jax.Array
    state: ADMMState
    """Pass back as ``warm_start`` next time."""
    primal_residual: jax.Array
    """``max |Ax - z|`` (constraint violation, in the units of A's rows)."""
    dual_residual: jax.Array
    """``max |Px + q + A'y|``."""


def zero_state(num_variables: int, num_constraints: int, dtype=None) -> ADMMState:
    dtype = dtype or jnp.zeros(()).dtype
    return ADMMState(
        jnp.zeros(num_variables, dtype),
        jnp.zeros(num_constraints, dtype),
        jnp.zeros(num_constraints, dtype),
    )


def solve_qp(
    P,
    q,
    A,
    lower,
    upper,
    iterations: int = 100,
    rho: float = 0.1,
    rho_equality_scale: float = 1e3,
    sigma: float = 1e-6,
    alpha: float = 1.6,
    adapt_every: int = 25,
    warm_start: ADMMState | None = None,
) -> ADMMResult:
    """Run ``iterations`` ADMM steps on the QP (see the module doc).

    Every ``adapt_every`` iterations ``rho`` is rescaled to balance the normalised primal
    and dual residuals (OSQP's rule) and the small KKT matrix is refactored: badly scaled
    problems (e.g. a heavily weighted soft task) then converge without tuning ``rho``.
    ``adapt_every = 0`` keeps ``rho`` fixed.
    """
    n, m = P.shape[0], A.shape[0]
    state = zero_state(n, m, P.dtype) if warm_start is None else warm_start
    is_eq = (upper - lower) < 1e-9
    eye = jnp.eye(n, dtype=P.dtype)
    block = iterations if adapt_every <= 0 else min(adapt_every, iterations)
    blocks = -(-iterations // block)

    def run_block(carry, _):
        s, rho_now = carry
        rho_vec = jnp.where(is_eq, rho_now * rho_equality_scale, rho_now)
        chol = jax.scipy.linalg.cho_factor(P + sigma * eye + A.T @ (rho_vec[:, None] * A))

        def step(s: ADMMState, _):
            rhs = sigma * s.x - q + A.T @ (rho_vec * s.z - s.y)
            x_tilde = jax.scipy.linalg.cho_solve(chol, rhs)
            z_tilde = A @ x_tilde
            x = alpha * x_tilde + (1.0 - alpha) * s.x
            z_relaxed = alpha * z_tilde + (1.0 - alpha) * s.z
            z = jnp.clip(z_relaxed + s.y / rho_vec, lower, upper)
            y = s.y + rho_vec * (z_relaxed - z)
            return ADMMState(x, z, y), None

        s, _ = jax.lax.scan(step, s, None, length=block)
        if adapt_every > 0:
            ax, px, aty = A @ s.x, P @ s.x, A.T @ s.y
            prim = jnp.max(jnp.abs(ax - s.z)) / (
                jnp.maximum(jnp.max(jnp.abs(ax)), jnp.max(jnp.abs(s.z))) + 1e-12
            )
            dual = jnp.max(jnp.abs(px + q + aty)) / (
                jnp.maximum(
                    jnp.maximum(jnp.max(jnp.abs(px)), jnp.max(jnp.abs(aty))), jnp.max(jnp.abs(q))
                )
                + 1e-12
            )
            rho_now = jnp.clip(rho_now * jnp.sqrt(prim / (dual + 1e-12)), 1e-6, 1e6)
        return (s, rho_now), None

    (state, _), _ = jax.lax.scan(run_block, (state, jnp.asarray(rho, P.dtype)), None, length=blocks)
    primal = jnp.max(jnp.abs(A @ state.x - state.z))
    dual = jnp.max(jnp.abs(P @ state.x + q + A.T @ state.y))
    return ADMMResult(state.x, state, primal, dual)
