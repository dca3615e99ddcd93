"""The reaction-force QP of WBLC (paper Eq. 14-15), solved by unrolled consensus ADMM.

For contact points ``p_i`` (3-D force ``f_i`` each) around the centre of mass ``c``::

    min  sum_i w_t (fx^2 + fy^2) + w_n fz^2 + w_ang |F_ang_des - W_ang f|^2
    s.t. W_lin f = F_lin_des                    (linear CoM behaviour: hard)
         f_i in C_i:  |fx|, |fy| <= mu fz,  fz_min <= fz <= fz_max_i,  |fx|, |fy| <= ft_max
         f_i = 0                                (points not in contact)

with ``W_lin f = sum f_i`` and ``W_ang f = sum (p_i - c) x f_i``. Weights and bounds default
to the authors' published values.

**Which cone.** The moment is soft, so the QP is feasible exactly when the net force can be
split over the points within their sets. Every pyramid is the same world-aligned one, so
that is a closed-form test on the net force (:func:`net_force_feasible`): ``Fz`` within the
sum of the normal-force bounds and ``max(|Fx|, |Fy|) <= mu min(Fz, sum_i min(fz_max_i,
ft_max / mu))``. When it fails with ``mu`` the QP is solved with ``mu_relaxed`` (1.75, as the
paper) and ``relaxed`` is set; when it fails even then, ``infeasible`` is set and the forces
are the best split within the relaxed sets (the net force is missed by ``linear_residual``).
One cone is solved per call, and the choice does not depend on how far the iterations got.

**Splitting.** ADMM on ``f = z`` (Boyd et al., 2011, consensus form): the ``f``-step is the
equality-constrained QP of the objective plus ``rho/2 |f - z + u|^2``, an affine map of
``z - u`` fixed for the call (``M (z - u) + c``, formed once by Woodbury from the diagonal
weights and the rank-3 moment term, with the net force as a 3-row equality); the ``z``-step
is each point's Euclidean projection onto ``C_i``, in closed form (:func:`project_point`).
So an iteration is one 3n x 3n mat-vec and a few elementwise operations (:func:`admm`),
batches well under ``vmap``, and differentiates through ``lax.scan``. The returned forces
are the projected iterate ``z``: they meet the cone and bounds exactly, and the net force
within ``linear_residual``. Variables are in units of ``force_scale`` newtons, ordered
coordinate-major (all ``x``, all ``y``, all ``z``) so that each component is a contiguous
row.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from jaxloco import validation as v
from jaxloco.control.triangular import lower_triangular_inverse


@dataclasses.dataclass(frozen=True)
class ForceQPParams:
    mu: float = 0.65
    """Friction coefficient of the nominal pyramid."""
    mu_relaxed: float = 1.75
    """The relaxed pyramid, used when the nominal one cannot carry the net force."""
    fz_min: float = 5.0
    """Least normal force of a point in contact (N)."""
    fz_max: float = 3000.0
    """Largest normal force of a point in contact (N); ``fz_max`` per point overrides it."""
    ft_max: float = 1000.0
    """Largest tangential force per axis (N)."""
    weight_tangential: float = 1.0
    """Weight of the tangential forces squared, ``w_t`` (forces in ``force_scale`` units)."""
    weight_normal: float = 0.5
    """Weight of the normal forces squared, ``w_n``."""
    weight_angular: float = 5000.0
    """Weight of the CAM rate's miss squared, ``w_ang``: the moment is soft, and this makes it
    nearly hard."""
    iterations: int = 500
    """ADMM iterations (unrolled). The default is for a cold start: against quadprog on
    1000 random single and double support problems every objective is within 1e-3 relative
    (``tests/test_force_qp.py``); a warm-started closed loop needs far fewer
    (``presets.CLOSED_LOOP_QP``)."""
    rho: float = 0.04
    """ADMM penalty, relative to the objective's mean diagonal (which the moment term
    dominates); the cold default is the value that met quadprog on the most random
    problems (docs/control.md)."""
    alpha: float = 1.6
    """Over-relaxation of the ``z``-step (1: none; OSQP's default 1.6)."""
    force_scale: float = 100.0
    """Forces are solved in units of this many newtons (conditioning)."""
    torque_rho: float = 3.0
    """ADMM penalty of the torque-limit rows (with :class:`TorqueRows`, each row scaled to
    unit norm), relative to ``rho``: the value that met quadprog best on random leg-like
    rows (docs/architecture.md, measured choices)."""
    torque_dual_max: float = 100.0
    """Bound on the scaled dual of each torque-limit row. Where the forces cannot bring a
    torque within its limit (a push beyond what the legs carry), an unbounded dual would
    grow tick after tick and pull the forces off the net-force equality; bounded, a
    violated row is an exact L1 penalty of this weight (times the penalty) and the
    violation is reported (``torque_excess``). Too small a bound cuts into feasible rows
    (docs/architecture.md, measured choices)."""

    def __post_init__(self):
        v.check_fields(
            self,
            [
                ("mu", 0 < self.mu < self.mu_relaxed, f"in (0, mu_relaxed = {self.mu_relaxed})"),
                ("fz_min", 0 <= self.fz_min < self.fz_max, f"in [0, fz_max = {self.fz_max})"),
                (
                    "ft_max",
                    self.mu_relaxed * self.fz_min <= self.ft_max,
                    f">= mu_relaxed * fz_min = {self.mu_relaxed * self.fz_min} (the least "
                    "normal force must allow its own friction)",
                ),
                v.integer(self, "iterations", 1),
                *v.positive(self, "rho"),
                ("alpha", 0 < self.alpha < 2, "in (0, 2)"),
                *v.positive(
                    self,
                    "force_scale",
                    "weight_tangential",
                    "weight_normal",
                    "weight_angular",
                    "torque_rho",
                    "torque_dual_max",
                ),
            ],
        )


@struct.dataclass
class ForceQPState:
    """ADMM's iterate, passed back as ``warm_start`` next tick (units of ``force_scale``)."""

    z: jax.Array
    """(3, n) projected forces, rows ``x, y, z`` components."""
    u: jax.Array
    """(3, n) scaled dual of ``f = z``."""
    torque_z: jax.Array
    """(m,) torque rows' projected values (each row scaled to unit norm in the force
    units; ``m = 0`` without :class:`TorqueRows`)."""
    torque_u: jax.Array
    """(m,) their scaled duals."""


@struct.dataclass
class ForceQPSolution:
    forces: jax.Array
    """(n, 3) contact forces (N), world frame; within each point's set exactly."""
    angular: jax.Array
    """(3,) achieved W_ang f (N m): the CAM rate the forces produce (Eq. 15)."""
    linear_residual: jax.Array
    """``max |W_lin f - F_lin_des|`` (N): the net force missed."""
    primal_residual: jax.Array
    """``max |f - z|`` (N) between ADMM's two iterates: how far from converged."""
    relaxed: jax.Array
    """True when the nominal pyramid cannot carry the net force and ``mu_relaxed`` was
    used."""
    infeasible: jax.Array
    """True when not even the relaxed pyramid can: ``linear_residual`` is then large."""
    torque_excess: jax.Array
    """With :class:`TorqueRows`: the largest amount (N m) by which the forces leave a
    torque beyond its limit (0 within every limit, and without rows; equality rows are not
    counted)."""
    warm_start: ForceQPState
    """Pass back next tick."""


def zero_warm_start(num_points: int, dtype=None, num_torques: int = 0) -> ForceQPState:
    """The ``warm_start`` of a first solve (``num_torques``: rows of :class:`TorqueRows`)."""
    dtype = dtype or jnp.zeros(()).dtype
    zero, rows = jnp.zeros((3, num_points), dtype), jnp.zeros((num_torques,), dtype)
    return ForceQPState(zero, zero, rows, rows)


@struct.dataclass
class TorqueRows:
    """Actuator torques as an affine map of the contact forces, and their limits: the
    constraint ``|offset - matrix @ f| <= limit`` (N m), ``f`` the (3n,) forces in N,
    coordinate-major (all ``x``, all ``y``, all ``z``)."""

    matrix: jax.Array
    """(m, 3n) N m per N."""
    offset: jax.Array
    """(m,) the torques at zero contact force (N m)."""
    limit: jax.Array
    """(m,) each row's bound (N m, finite; 0: the row is an equality, ``offset = matrix
    f``)."""


def net_force_feasible(f_lin, in_contact, fz_max, mu, params: ForceQPParams):
    """Whether the points in contact can carry the net force ``f_lin`` (N) within their
    pyramids ``mu`` and bounds (see the module doc; exact for world-aligned pyramids)."""
    on = in_contact.astype(f_lin.dtype)
    fz_lo = params.fz_min * jnp.sum(on)
    fz_hi = jnp.sum(on * fz_max)
    # Most tangential force per axis for a normal force Fz: each point gives
    # mu * min(fz_i, ft_max / mu); the Fz beyond the caps' sum adds nothing.
    capped = jnp.sum(on * jnp.minimum(fz_max, params.ft_max / mu))
    tangential = mu * jnp.minimum(f_lin[2], capped)
    return (
        (f_lin[2] >= fz_lo)
        & (f_lin[2] <= fz_hi)
        & (jnp.maximum(jnp.abs(f_lin[0]), jnp.abs(f_lin[1])) <= tangential)
        & (jnp.sum(on) > 0)
    )


def project_point(fx, fy, fz, fz_lo, fz_hi, mu, ft_max):
    """Euclidean projection of forces ``(fx, fy, fz)`` (elementwise arrays) onto
    ``{|x|, |y| <= min(mu z, ft_max), fz_lo <= z <= fz_hi}``.

    For a fixed ``z`` the best ``x`` is ``clip(fx, -cap, cap)`` with ``cap = min(mu z,
    ft_max)``, so ``z`` minimises the convex piecewise quadratic ``(z - fz)^2 + sum_k
    max(|f_k| - min(mu z, ft_max), 0)^2`` over ``[fz_lo, fz_hi]``. Component ``k`` pulls on
    ``z`` while ``z < beta_k = min(|f_k|, ft_max) / mu``; on the three pieces the stationary
    points are ``z_2`` (both pull), ``z_1`` (the one with the larger ``beta``) and ``fz``,
    and the unconstrained minimiser is ``max(min(z_2, beta_lo), min(z_1, beta_hi), fz)``
    (the derivative is continuous and non-decreasing). No comparisons of objective values,
    so the result does not depend on round-off in them.
    """
    ax, ay = jnp.abs(fx), jnp.abs(fy)
    beta_x, beta_y = jnp.minimum(ax, ft_max) / mu, jnp.minimum(ay, ft_max) / mu
    beta_lo, beta_hi = jnp.minimum(beta_x, beta_y), jnp.maximum(beta_x, beta_y)
    a_hi = jnp.where(beta_x >= beta_y, ax, ay)
    z_2 = (fz + mu * (ax + ay)) / (1.0 + 2.0 * mu * mu)
    z_1 = (fz + mu * a_hi) / (1.0 + mu * mu)
    z_free = jnp.maximum(jnp.maximum(jnp.minimum(z_2, beta_lo), jnp.minimum(z_1, beta_hi)), fz)
    z = jnp.clip(z_free, fz_lo, fz_hi)
    cap = jnp.minimum(mu * z, ft_max)
    return jnp.clip(fx, -cap, cap), jnp.clip(fy, -cap, cap), z


def _inv3(m):
    """Inverse of a 3x3 matrix by its adjugate: elementwise code, no LAPACK call (these
    are symmetric positive definite here)."""
    a, b, c = m[0]
    d, e, f = m[1]
    g, h, i = m[2]
    cof = jnp.stack(
        [
            jnp.stack([e * i - f * h, c * h - b * i, b * f - c * e]),
            jnp.stack([f * g - d * i, a * i - c * g, c * d - a * f]),
            jnp.stack([d * h - e * g, b * g - a * h, a * e - b * d]),
        ]
    )
    det = a * cof[0, 0] + b * cof[1, 0] + c * cof[2, 0]
    return cof / det


def moment_map(points, in_contact, com):
    """``W_ang`` (3, 3n): the moment about ``com`` of forces at ``points`` (coordinate-major
    columns); points out of contact take no part."""
    n = points.shape[0]
    r = (points - com) * in_contact.astype(points.dtype)[:, None]
    zero = jnp.zeros(n, points.dtype)
    return jnp.stack(
        [
            jnp.concatenate([zero, -r[:, 2], r[:, 1]]),
            jnp.concatenate([r[:, 2], zero, -r[:, 0]]),
            jnp.concatenate([-r[:, 1], r[:, 0], zero]),
        ]
    )


class AffineStep(NamedTuple):
    """ADMM's ``f``-step as an affine map ``f = matrix v + offset`` (scaled force units,
    coordinate-major: ``f`` is ``(3n,)``, rows ``x``, then ``y``, then ``z``)."""

    matrix: jax.Array
    """(3n, 3n): the map of ``v = z - u``; with torque rows (3n + m, 3n + m), the map of
    ``[v; z_t - u_t]`` to ``[f; rows f]`` (:func:`affine_step_with_torques`)."""
    offset: jax.Array
    """(3n,) the constant part ``c`` (with torque rows (3n + m,), ``[c; rows c]``)."""
    moment_map: jax.Array
    """(3, 3n) ``W_ang``: the moment of the forces about the CoM."""


def affine_step(points, in_contact, com, f_lin, f_ang, params: ForceQPParams) -> AffineStep:
    """The ADMM ``f``-step as ``f = M v + c`` (``v = z - u``, all ``(3n,)``, scaled units,
    coordinate-major), and the moment map ``W_ang`` ``(3, 3n)``.

    ``f`` minimises ``1/2 f'Pf + q'f + rho/2 |f - v|^2`` subject to ``W_lin f = F_lin / s``,
    with ``P = 2 (D + w_ang W_ang' W_ang) / k`` (``k``: its mean diagonal, so that one
    ``rho`` suits every configuration). ``G = (P + rho I)^-1`` is diagonal plus rank 3
    (Woodbury) and the equality adds a 3 x 3 Schur complement: ``M = rho Pi``, ``c = -Pi q
    + G W_lin' S^-1 e`` with ``Pi = G - G W_lin' S^-1 W_lin G``.
    """
    dtype = points.dtype
    n = points.shape[0]
    s = params.force_scale
    on = in_contact.astype(dtype)
    r = (points - com) * on[:, None]  # points out of contact take no part
    w_ang = moment_map(points, in_contact, com)
    w_lin = jnp.kron(jnp.eye(3, dtype=dtype), on[None, :])  # (3, 3n)
    weights = jnp.repeat(
        jnp.asarray(
            [params.weight_tangential, params.weight_tangential, params.weight_normal], dtype
        ),
        n,
    )
    w = params.weight_angular
    k = 2.0 * (jnp.mean(weights) + w * jnp.sum(r * r) * 2.0 / (3 * n))  # mean diag of P
    rho = params.rho
    d_rho = 2.0 * weights / k + rho  # diagonal of P + rho I without the moment term
    wd = w_ang / d_rho  # W_ang D_rho^-1
    # Woodbury: (D_rho + (2w/k) W'W)^-1 = D_rho^-1 - (W D_rho^-1)' K^-1 (W D_rho^-1).
    kmat = (k / (2.0 * w)) * jnp.eye(3, dtype=dtype) + wd @ w_ang.T
    g = jnp.diag(1.0 / d_rho) - wd.T @ _inv3(kmat) @ wd
    q = -(2.0 * w / k) * (w_ang.T @ (f_ang / s))
    g_lin = g @ w_lin.T  # (3n, 3)
    # With no point in contact W_lin = 0: a floor keeps S invertible (f is then 0 anyway);
    # in contact S is ~1e2 and the floor is below its round-off.
    schur = w_lin @ g_lin + jnp.eye(3, dtype=dtype) * jnp.finfo(dtype).eps
    schur_inv = _inv3(schur)
    pi = g - g_lin @ schur_inv @ g_lin.T
    return AffineStep(rho * pi, g_lin @ (schur_inv @ (f_lin / s)) - pi @ q, w_ang)


def admm(matrix, offset, fz_lo, fz_hi, mu, params: ForceQPParams, warm: ForceQPState):
    """``params.iterations`` consensus ADMM steps from ``warm``; returns the new state and
    the last ``f``-step (all scaled units).

    After the first step the iterate is carried as ``t = z + u`` (the point the ``z``-step
    projects, so ``z = proj(t)`` and ``u = t - z``) and ``w = z - u = 2 proj(t) - t`` (the
    next ``f``-step's argument): a step is then ``t <- t + alpha (M w + c - z)`` with
    ``z = (w + t) / 2``, and ``w <- 2 proj(t) - t``, the same iterates as the ``(z, u)``
    form up to round-off. Per step XLA:CPU runs four kernels (the mat-vec, the update of
    ``t``, the projection, the loop counter) instead of ~11: the ``(z, u)`` form needs
    ``z``, ``u`` and ``z - u`` materialised, and a stacked projection is compiled per
    output element. Batched, a step is bound by how many kernels it dispatches.
    """
    n = fz_lo.shape[0]
    alpha = params.alpha
    ft_max = params.ft_max / params.force_scale
    row = jnp.arange(3)[:, None]

    def f_step(v):
        return (matrix @ v.reshape(-1) + offset).reshape(3, n)

    def project(t):
        # Selected by row rather than stacked: XLA:CPU compiles a stack of the three
        # projected rows as scalar code, and the selects as vector code.
        fx, fy, fz = project_point(t[0], t[1], t[2], fz_lo, fz_hi, mu, ft_max)
        return jnp.where(row == 0, fx, jnp.where(row == 1, fy, fz))

    def step(carry, _):
        t, w = carry
        t = t + alpha * (f_step(w) - 0.5 * (w + t))
        return (t, 2.0 * project(t) - t), None

    # The first step from (z, u) as given: a warm start need not satisfy z = proj(z + u).
    t = alpha * f_step(warm.z - warm.u) + (1.0 - alpha) * warm.z + warm.u
    (t, _), _ = jax.lax.scan(step, (t, 2.0 * project(t) - t), None, length=params.iterations - 1)
    z = project(t)
    u = t - z
    return ForceQPState(z, u, warm.torque_z, warm.torque_u), f_step(z - u)


def affine_step_with_torques(
    points, in_contact, com, f_lin, f_ang, params: ForceQPParams, rows
) -> AffineStep:
    """The ``f``-step with torque-limit rows ``rows`` ((m, 3n) map of the scaled forces to
    torques in units of their limits), stacked with the rows' values: ``[f; rows f] = M
    [v; v_t] + c``, ``M`` (3n + m, 3n + m), from ``1/2 f'Pf + q'f + rho/2 |f - v|^2 +
    rho_t/2 |rows f - v_t|^2`` subject to the net force (``P``, ``q`` as
    :func:`affine_step`; ``rho_t = torque_rho * rho``). The rows make it dense: one
    Cholesky factorisation of the (3n, 3n) ``P + rho I + rho_t rows' rows``. With ``Pi``
    the equality-constrained inverse and ``X = Pi rows'``, ``M = [[rho Pi, rho_t X],
    [rho X', rho_t rows X]]``: the ADMM step's one mat-vec gives the forces and their
    torque rows together."""
    dtype = points.dtype
    n = points.shape[0]
    s = params.force_scale
    on = in_contact.astype(dtype)
    r = (points - com) * on[:, None]
    w_ang = moment_map(points, in_contact, com)
    w_lin = jnp.kron(jnp.eye(3, dtype=dtype), on[None, :])
    weights = jnp.repeat(
        jnp.asarray(
            [params.weight_tangential, params.weight_tangential, params.weight_normal], dtype
        ),
        n,
    )
    w = params.weight_angular
    k = 2.0 * (jnp.mean(weights) + w * jnp.sum(r * r) * 2.0 / (3 * n))
    rho = params.rho
    rho_t = params.torque_rho * rho
    hessian = (
        jnp.diag(2.0 * weights / k + rho) + (2.0 * w / k) * w_ang.T @ w_ang + rho_t * rows.T @ rows
    )
    chol_inv = lower_triangular_inverse(jnp.linalg.cholesky(hessian))
    h_inv = chol_inv.T @ chol_inv
    q = -(2.0 * w / k) * (w_ang.T @ (f_ang / s))
    g_lin = h_inv @ w_lin.T
    schur = w_lin @ g_lin + jnp.eye(3, dtype=dtype) * jnp.finfo(dtype).eps
    schur_inv = _inv3(schur)
    pi = h_inv - g_lin @ schur_inv @ g_lin.T
    x = pi @ rows.T  # Pi is symmetric: rows Pi = X'
    matrix = jnp.block([[rho * pi, rho_t * x], [rho * x.T, rho_t * (rows @ x)]])
    offset = g_lin @ (schur_inv @ (f_lin / s)) - pi @ q
    return AffineStep(matrix, jnp.concatenate([offset, rows @ offset]), w_ang)


def admm_with_torques(matrix, offset, lo, hi, fz_lo, fz_hi, mu, params, warm):
    """ADMM on ``[f; rows f] = [z; z_t]`` (OSQP's splitting, over-relaxed): ``z`` projected
    on the points' sets, ``z_t`` clipped to ``[lo, hi]``; the torque rows' scaled duals
    bounded by ``torque_dual_max`` (see :class:`ForceQPParams`). ``matrix``, ``offset``:
    :func:`affine_step_with_torques`'s map of ``[v; v_t]`` to ``[f; rows f]``. Returns the
    state and the last ``f``-step.

    As :func:`admm`, the force block is carried as ``t = f_rel + u`` (``z = proj(t)``,
    ``u = t - z``), and ``rows f`` comes out of the same mat-vec as ``f``: per step one
    mat-vec and the element-wise updates, the same iterates as the ``(z, u, z_t, u_t)``
    form up to round-off."""
    n = fz_lo.shape[0]
    alpha = params.alpha
    ft_max = params.ft_max / params.force_scale
    dual_max = params.torque_dual_max
    row = jnp.arange(3)[:, None]

    def project(t):
        fx, fy, fz = project_point(t[0], t[1], t[2], fz_lo, fz_hi, mu, ft_max)
        return jnp.where(row == 0, fx, jnp.where(row == 1, fy, fz))

    def steps(w, zt, ut):
        """``[f; rows f]`` at ``v = [w; z_t - u_t]`` (``w = z - u``)."""
        y = matrix @ jnp.concatenate([w.reshape(-1), zt - ut]) + offset
        return y[: 3 * n].reshape(3, n), y[3 * n :]

    def torque_block(g, zt, ut):
        t_rel = alpha * g + (1.0 - alpha) * zt
        zt_new = jnp.clip(t_rel + ut, lo, hi)
        return zt_new, jnp.clip(ut + t_rel - zt_new, -dual_max, dual_max)

    def step(carry, _):
        # w = 2 proj(t) - t is carried, not recomputed: XLA:CPU fused the projection into
        # each consumer (the mat-vec's argument, the update of t) as scalar code.
        t, w, zt, ut = carry
        f, g = steps(w, zt, ut)
        t = t + alpha * (f - 0.5 * (w + t))
        return (t, 2.0 * project(t) - t, *torque_block(g, zt, ut)), None

    # The first step from (z, u) as given: a warm start need not satisfy z = proj(z + u).
    zt0, ut0 = warm.torque_z, jnp.clip(warm.torque_u, -dual_max, dual_max)
    f, g = steps(warm.z - warm.u, zt0, ut0)
    t = alpha * f + (1.0 - alpha) * warm.z + warm.u
    carry = (t, 2.0 * project(t) - t, *torque_block(g, zt0, ut0))
    (t, w, zt, ut), _ = jax.lax.scan(step, carry, None, length=params.iterations - 1)
    z = 0.5 * (w + t)
    u = t - z
    return ForceQPState(z, u, zt, ut), steps(w, zt, ut)[0].reshape(-1)


def solve_contact_forces(
    points,
    in_contact,
    com,
    f_lin,
    f_ang,
    params: ForceQPParams = ForceQPParams(),
    fz_max=None,
    warm_start: ForceQPState | None = None,
    torques: TorqueRows | None = None,
) -> ForceQPSolution:
    """Contact forces for a desired CoM force ``f_lin = m (a_com + g)`` and CAM rate ``f_ang``.

    ``points`` (n, 3) world contact points, ``in_contact`` (n,) bool, ``com`` (3,).
    ``fz_max``: optional per-point upper normal-force bound (N; contact blending).
    ``warm_start``: the previous solution's ``warm_start``.
    ``torques``: actuator torques as a map of the forces, to be kept within their limits
    (the QP gains the rows ``|offset - matrix f| <= limit``; ``warm_start`` must then have
    as many torque rows: ``zero_warm_start(n, dtype, m)``).
    """
    points, com = jnp.asarray(points), jnp.asarray(com)
    dtype = points.dtype
    n = points.shape[0]
    in_contact = jnp.asarray(in_contact, bool)
    f_lin, f_ang = jnp.asarray(f_lin, dtype), jnp.asarray(f_ang, dtype)
    fz_max = jnp.full((n,), params.fz_max, dtype) if fz_max is None else fz_max
    fz_max = jnp.asarray(fz_max, dtype)
    m = 0 if torques is None else torques.offset.shape[0]
    if warm_start is None:
        warm_start = zero_warm_start(n, dtype, m)
    if warm_start.torque_z.shape != (m,):
        raise ValueError(
            f"solve_contact_forces: warm_start has {warm_start.torque_z.shape[0]} torque rows, "
            f"the problem {m}"
        )
    # Non-finite commands or geometry (a fallen or exploded state): solve a zero problem,
    # flagged infeasible, rather than let NaN reach the torques.
    finite = jnp.all(jnp.isfinite(f_lin)) & jnp.all(jnp.isfinite(f_ang))
    finite = finite & jnp.all(jnp.isfinite(points)) & jnp.all(jnp.isfinite(com))
    f_lin, f_ang = jnp.where(finite, f_lin, 0.0), jnp.where(finite, f_ang, 0.0)
    points, com = jnp.where(finite, points, 0.0), jnp.where(finite, com, 0.0)
    warm_start = jax.tree.map(
        lambda a: jnp.where(finite & jnp.all(jnp.isfinite(a)), a, 0.0), warm_start
    )
    nominal_ok = net_force_feasible(f_lin, in_contact, fz_max, params.mu, params)
    relaxed_ok = net_force_feasible(f_lin, in_contact, fz_max, params.mu_relaxed, params)
    mu = jnp.where(nominal_ok, params.mu, params.mu_relaxed).astype(dtype)
    s = params.force_scale
    fz_lo = jnp.where(in_contact, params.fz_min / s, 0.0).astype(dtype)
    # fz_max below fz_min (a contact blending in): the point carries exactly fz_min.
    fz_hi = jnp.where(in_contact, jnp.maximum(fz_max, params.fz_min) / s, 0.0).astype(dtype)
    if torques is None:
        step = affine_step(points, in_contact, com, f_lin, f_ang, params)
        state, f = admm(step.matrix, step.offset, fz_lo, fz_hi, mu, params, warm_start)
        f = f.reshape(-1)
        torque_excess = jnp.zeros((), dtype)
    else:
        # Rows in units of each limit, forces in units of force_scale: |tau0 - G f| <= l
        # reads lo <= rows f <= hi with rows = G s / l.
        limit = jnp.asarray(torques.limit, dtype)
        offset_t = jnp.where(finite, jnp.asarray(torques.offset, dtype), 0.0)
        g_scaled = jnp.where(finite, jnp.asarray(torques.matrix, dtype), 0.0) * s
        # Each row scaled to unit norm (equilibrated, so one penalty suits every row);
        # a row the forces do not reach keeps a tiny norm and its violation is reported.
        norm = jnp.maximum(jnp.linalg.norm(g_scaled, axis=1), jnp.finfo(dtype).tiny)
        rows = g_scaled / norm[:, None]
        lo, hi = (offset_t - limit) / norm, (offset_t + limit) / norm
        # Zero rows (bounds 0) pad the variables to a multiple of 8: XLA:CPU's mat-vecs
        # vectorise whole (docs/architecture.md, measured choices).
        m = rows.shape[0]
        pad = -(points.shape[0] * 3 + m) % 8
        padded = jnp.pad(rows, ((0, pad), (0, 0)))
        warm_padded = warm_start.replace(
            torque_z=jnp.pad(warm_start.torque_z, (0, pad)),
            torque_u=jnp.pad(warm_start.torque_u, (0, pad)),
        )
        step = affine_step_with_torques(points, in_contact, com, f_lin, f_ang, params, padded)
        state, f = admm_with_torques(
            step.matrix,
            step.offset,
            jnp.pad(lo, (0, pad)),
            jnp.pad(hi, (0, pad)),
            fz_lo,
            fz_hi,
            mu,
            params,
            warm_padded,
        )
        state = state.replace(torque_z=state.torque_z[:m], torque_u=state.torque_u[:m])
        tau = offset_t - (rows @ state.z.reshape(-1)) * norm
        # Equality rows (limit 0) are not limits: what they miss shows in the caller's
        # own residuals (WBLC's base_residual).
        over = jnp.where(limit > 0, jnp.abs(tau) - limit, 0.0)
        torque_excess = jnp.max(jnp.maximum(over, 0.0))
    forces = state.z.T * s
    return ForceQPSolution(
        forces=forces,
        angular=(step.moment_map @ state.z.reshape(-1)) * s,
        linear_residual=jnp.max(jnp.abs(jnp.sum(forces, axis=0) - f_lin)),
        primal_residual=jnp.max(jnp.abs(f - state.z.reshape(-1))) * s,
        relaxed=~nominal_ok,
        infeasible=~(relaxed_ok & finite),
        torque_excess=torque_excess,
        warm_start=state,
    )
