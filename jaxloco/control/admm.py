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
    polished: jax.Array = None
    """True where the active-set polish was accepted (see :func:`polish`)."""


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
    unroll: int = 1,
    a_ops: tuple | None = None,
) -> ADMMResult:
    """Run ``iterations`` ADMM steps on the QP (see the module doc).

    Every ``adapt_every`` iterations ``rho`` is rescaled to balance the normalised primal
    and dual residuals (OSQP's rule) and the small KKT matrix is refactored: badly scaled
    problems (e.g. a heavily weighted soft task) then converge without tuning ``rho``.
    ``adapt_every = 0`` keeps ``rho`` fixed. ``unroll``: iterations per loop trip, a
    speed knob that leaves the numbers as they are; under ``vmap`` on XLA:CPU more
    unrolling ran slower (measurements at :class:`~jaxloco.control.force_qp.ForceQPParams`).
    ``a_ops``: optional ``(x -> A x, y -> A' y)`` exploiting A's structure inside the
    iterations (A stays dense for the factorisation and the residuals).
    """
    n, m = P.shape[0], A.shape[0]
    a_mul, at_mul = (lambda x: A @ x, lambda y: A.T @ y) if a_ops is None else a_ops
    state = zero_state(n, m, P.dtype) if warm_start is None else warm_start
    is_eq = (upper - lower) < 1e-9
    eye = jnp.eye(n, dtype=P.dtype)
    block = iterations if adapt_every <= 0 else min(adapt_every, iterations)
    blocks = -(-iterations // block)

    def run_block(carry, _):
        s, rho_now = carry
        rho_vec = jnp.where(is_eq, rho_now * rho_equality_scale, rho_now)
        chol = jax.scipy.linalg.cho_factor(P + sigma * eye + A.T @ (rho_vec[:, None] * A))
        # The explicit inverse turns each iteration's solve into a mat-vec: for these small
        # systems a LAPACK call per iteration costs more than the arithmetic.
        kkt_inv = jax.scipy.linalg.cho_solve(chol, eye)

        def step(s: ADMMState, _):
            rhs = sigma * s.x - q + at_mul(rho_vec * s.z - s.y)
            x_tilde = kkt_inv @ rhs
            z_tilde = a_mul(x_tilde)
            x = alpha * x_tilde + (1.0 - alpha) * s.x
            z_relaxed = alpha * z_tilde + (1.0 - alpha) * s.z
            z = jnp.clip(z_relaxed + s.y / rho_vec, lower, upper)
            y = s.y + rho_vec * (z_relaxed - z)
            return ADMMState(x, z, y), None

        s, _ = jax.lax.scan(step, s, None, length=block, unroll=unroll)
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


def _kkt_point(P, q, A, lower, upper, at_lower, at_upper, delta, refinements, l_inv, h_at, gram):
    """Solve the equality-constrained QP on a guessed active set; say whether the result
    satisfies the KKT conditions of the full QP. ``l_inv`` (inverse of the lower Cholesky factor of
    ``H = P + dI``), ``h_at = H^-1 A'`` and ``gram = A H^-1 A'`` do not depend on the guess
    and are shared between steps."""
    dtype = P.dtype
    is_eq = (upper - lower) < 1e-9
    at_lower = at_lower | is_eq
    at_upper = at_upper & ~is_eq
    d = (at_lower | at_upper).astype(dtype)
    target = jnp.where(at_upper, upper, lower) * d
    # The quasi-definite KKT system [[P + dI, A_a'], [A_a, -dI]] by its Schur complement
    # (Cholesky; LU under vmap has hung XLA:CPU at large batches).
    ad = A * d[:, None]
    schur = gram * d[:, None] * d[None, :] + jnp.diag(delta * d + (1.0 - d))
    s_chol = jax.scipy.linalg.cho_factor(schur)
    h_at = h_at * d[None, :]

    def damped_solve(r_x, r_y):
        """Solve [[P + dI, A_a'], [A_a, -dI - (I - D)]] [x; y] = [r_x; r_y]."""
        h_rx = l_inv.T @ (l_inv @ r_x)
        y = jax.scipy.linalg.cho_solve(s_chol, ad @ h_rx - r_y)
        return h_rx - h_at @ y, y

    x, y = damped_solve(-q, target)
    for _ in range(refinements):  # against the undamped system
        dx, dy = damped_solve(-q - P @ x - ad.T @ y, target - ad @ x + (1.0 - d) * y)
        x, y = x + dx, y + dy
    y = y * d
    # Stationarity holds by construction; with primal feasibility and multipliers of the
    # right signs the KKT conditions hold and x is the optimum.
    signs_ok = jnp.all(jnp.where(at_upper, y >= -1e-9, True)) & jnp.all(
        jnp.where(at_lower & ~is_eq, y <= 1e-9, True)
    )
    ok = signs_ok & jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(y))
    return x, y, ok


def _violation(A, lower, upper, x):
    ax = A @ x
    return jnp.max(jnp.maximum(jnp.maximum(ax - upper, lower - ax), 0.0))


def polish(
    P,
    q,
    A,
    lower,
    upper,
    result: ADMMResult,
    steps: int = 4,
    delta: float = 1e-7,
    refinements: int = 3,
    dual_tolerance: float = 1e-7,
    violation_floor: float = 1e-9,
) -> ADMMResult:
    """Polish ADMM's answer to the exact optimum by a few primal-dual active-set steps.

    ADMM converges linearly, slowly on badly conditioned problems (here, a heavily
    weighted soft task), but its active set is nearly right long before its iterate is
    accurate. Starting from the rows whose ADMM dual is beyond ``dual_tolerance`` (the
    sign gives the bound; equalities always active), each step solves the
    equality-constrained QP on the guessed set exactly, then updates the guess by the
    primal-dual active-set rule (Hintermueller et al., 2002): a row is active at its lower
    bound when ``y + (Ax - l) < 0`` and at its upper bound when ``y + (Ax - u) > 0``, i.e.
    violated rows join and rows with multipliers of the wrong sign leave. Each KKT system
    ``[[P + dI, A_a'], [A_a, -dI]]`` is written over all rows (inactive rows become
    ``-y_i = 0``), solved through its Schur complement by Cholesky and refined
    ``refinements`` times against the undamped system. A point is accepted only when the
    KKT conditions hold (feasible to within ADMM's own violation or ``violation_floor``,
    whichever is larger, multipliers of the right signs), so polishing never degrades the
    result beyond that floor; ``polished`` says whether it was. The floor matters in float32:
    an ADMM iterate can meet an equality to the last bit while the exact KKT point misses it
    by rounding (~1e-6 of the row's scale), and a zero floor then rejected most polishes on
    the flip of a rounding error (session 25: 12 against 52 of 64 cold force QPs accepted,
    depending only on how XLA compiled the same solve).
    Shapes are static and the steps unrolled, so this batches and differentiates.
    """
    y = result.state.y
    z = result.state.z
    at_lower = (y < -dual_tolerance) | (z <= lower)
    at_upper = (y > dual_tolerance) | (z >= upper)
    admm_violation = jnp.maximum(_violation(A, lower, upper, result.x), violation_floor)
    x_out, y_out, accepted = result.x, y, jnp.asarray(False)
    eye = jnp.eye(P.shape[0], dtype=P.dtype)
    h_chol = jnp.linalg.cholesky(P + delta * eye)
    # gram = B'B with B = L^-1 A': positive semi-definite by construction. Formed as
    # A (P + dI)^-1 A' from an explicit inverse it was indefinite in float32 (P carries the
    # 5000-weighted angular term), and the Schur complement's Cholesky broke down (NaN).
    l_inv = jax.scipy.linalg.solve_triangular(h_chol, eye, lower=True)
    b = l_inv @ A.T
    gram = b.T @ b
    h_at = l_inv.T @ b
    # The dual damping must stay above the rounding of the Schur complement, or a guessed
    # active set with more rows than variables (singular on those rows) breaks its Cholesky:
    # in float32, 1e-7 against a largest entry ~7e4 did, and NaN failed the polish (session
    # 25). Iterative refinement removes the damping's bias where the system is regular.
    schur_delta = jnp.maximum(delta, jnp.finfo(P.dtype).eps * jnp.max(jnp.diag(gram)))
    for _ in range(steps):
        x, y_pol, ok = _kkt_point(
            P, q, A, lower, upper, at_lower, at_upper, schur_delta, refinements, l_inv, h_at, gram
        )
        ok = ok & (_violation(A, lower, upper, x) <= admm_violation) & ~accepted
        x_out = jnp.where(ok, x, x_out)
        y_out = jnp.where(ok, y_pol, y_out)
        accepted = accepted | ok
        ax = A @ x
        at_lower, at_upper = y_pol + (ax - lower) < 0.0, y_pol + (ax - upper) > 0.0
    z_out = jnp.where(accepted, jnp.clip(A @ x_out, lower, upper), result.state.z)
    state = ADMMState(x_out, z_out, y_out)
    primal = jnp.max(jnp.abs(A @ x_out - z_out))
    dual = jnp.max(jnp.abs(P @ x_out + q + A.T @ y_out))
    return ADMMResult(x_out, state, primal, dual, accepted)
