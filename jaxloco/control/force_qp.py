"""The reaction-force QP of WBLC (paper Eq. 14-15), solved by unrolled ADMM.

For contact points ``p_i`` (3-D force ``f_i`` each) around the centre of mass ``c``::

    min  sum_i w_t (fx^2 + fy^2) + w_n fz^2 + w_ang |F_ang_des - W_ang f|^2
    s.t. W_lin f = F_lin_des                    (linear CoM behaviour: hard)
         |fx|, |fy| <= mu fz                    (friction pyramid)
         fz_min <= fz <= fz_max, |fx|, |fy| <= ft_max     (points in contact)
         f = 0                                  (points not in contact)

with ``W_lin f = sum f_i`` and ``W_ang f = sum (p_i - c) x f_i``. Weights and bounds default
to the authors' (``shared/reference/paper-details.md``). When the pyramid with ``mu`` cannot
be met (the constraint violation after the iterations exceeds ``tolerance``), the solution
with ``mu_relaxed`` (1.75, as the paper) is used instead and ``relaxed`` is set. The achieved
angular part ``W_ang f`` is returned for Eq. 15. By default both cones are solved every time,
as one ``vmap``-ed batch of two (the choice is made after the fact); with
``relaxed_on_demand`` the relaxed cone is solved only where the nominal one failed (see
:func:`_relaxed_where_needed`). Shapes are static (a fixed number of points with an
``in_contact`` mask), so the solver batches with ``vmap``.

ADMM alone converges slowly on the badly conditioned cases (the 5000-weighted angular
term); :func:`admm.polish` finishes every solve with a few active-set steps. Against
quadprog on 1000 random feasible single and double support problems, 400 iterations plus
polish give a largest relative objective error of ~5e-14 and cone violations ~5e-13 N
(``tests/test_force_qp.py``; the accuracy-vs-iterations table is in
``benchmarks/bench_wblc.py``).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct
from jax.custom_batching import custom_vmap

from jaxloco.control import admm
from jaxloco.dynamics import se3

_BIG = 1e9


@dataclasses.dataclass(frozen=True)
class ForceQPParams:
    mu: float = 0.65
    mu_relaxed: float = 1.75
    fz_min: float = 5.0
    fz_max: float = 3000.0
    ft_max: float = 1000.0
    weight_tangential: float = 1.0
    weight_normal: float = 0.5
    weight_angular: float = 5000.0
    iterations: int = 400
    rho: float = 1.0
    adapt_every: int = 25
    """Rescale rho every this many iterations (0: fixed rho); see admm.solve_qp."""
    unroll: int = 1
    """ADMM iterations per loop trip (``lax.scan``'s ``unroll``), for speed. It changes
    the numbers only through XLA's float32 round-off: on 64 cold problems 1, 2 and 5 gave
    the same forces bit for bit, 25 forces up to 34 N apart. Measured on a 2-core VM for
    a batch of 64 problems (``vmap``, 200 iterations + 2 polish steps, both cones):
    376-397 us per problem at 1, 408 at 2, 466-507 at 5, 1283 at 25."""
    polish: bool = True
    """Finish with an active-set polish (admm.polish): exact on the tail of badly
    conditioned cases where ADMM alone is slow."""
    polish_steps: int = 4
    """Active-set steps of the polish (each one Cholesky of the constraint-sized Schur
    complement); warm-started closed loops need fewer."""
    force_scale: float = 100.0
    """Forces are solved in units of this many newtons (conditioning)."""
    tolerance: float = 1e-3
    """Constraint violation (N) above which the solution counts as not meeting the cone."""
    relaxed_on_demand: bool = False
    """Solve the relaxed cone only where the nominal one failed, instead of both every time.
    Under ``vmap`` the failed problems of the batch are gathered into ``relaxed_slots``
    slots (the whole batch when more fail), and nothing is solved when none did. Each
    robot's result does not depend on the rest of its batch. Its warm start is the previous
    relaxed solution if the previous tick relaxed, else the previous nominal one. Not
    reverse-differentiable (``jax.custom_batching.custom_vmap``): the tuning problems turn
    it off. Off by default: measured in session 25 (C backend, 2 workers), issue 7's 40-push
    step-4 sweep took 44.5 s instead of 50.2 s (-11%; the cone was relaxed at ~0.2-0.4% of
    robot-ticks) but recovered 38/40 against 40/40. ``bench_wblc.py --quick``: one jitted
    tick 2,075 against 3,151 us, but the batch-64 tick 939 against 929 us per robot (no gain;
    not traced; a stand-in without any relaxed solve had given 418 against 630-653)."""
    relaxed_slots: int = 8
    """``relaxed_on_demand``: relaxed problems solved as one gathered batch per tick."""

    def __post_init__(self):
        if not 0 < self.mu < self.mu_relaxed:
            raise ValueError(
                f"ForceQPParams: need 0 < mu < mu_relaxed; got {self.mu}, {self.mu_relaxed}"
            )
        if not 0 <= self.fz_min < self.fz_max:
            raise ValueError(
                f"ForceQPParams: need 0 <= fz_min < fz_max; got {self.fz_min}, {self.fz_max}"
            )
        if self.unroll < 1:
            raise ValueError(f"ForceQPParams.unroll must be >= 1; got {self.unroll}")
        if self.iterations < 1 or self.rho <= 0 or self.force_scale <= 0:
            raise ValueError("ForceQPParams: iterations >= 1, rho > 0 and force_scale > 0 required")
        if self.polish_steps < 1:
            raise ValueError(f"ForceQPParams.polish_steps must be >= 1; got {self.polish_steps}")
        if self.relaxed_slots < 1:
            raise ValueError(f"ForceQPParams.relaxed_slots must be >= 1; got {self.relaxed_slots}")


@struct.dataclass
class ForceQPSolution:
    forces: jax.Array
    """(n, 3) contact forces (N), world frame."""
    angular: jax.Array
    """(3,) achieved W_ang f: the CAM rate the forces produce (Eq. 15)."""
    linear_residual: jax.Array
    """max |W_lin f - F_lin_des| (N)."""
    violation: jax.Array
    """Largest violation of the cone and bounds actually used (N)."""
    dual_residual: jax.Array
    relaxed: jax.Array
    """True when mu_relaxed was needed."""
    warm_start: tuple
    """ADMM states (mu, mu_relaxed) to pass back next tick."""


def build_qp(points, in_contact, com, f_lin, f_ang, mu, params: ForceQPParams, fz_max=None):
    """The QP in scaled force units ``f / force_scale``: ``(P, q, A, l, u, W_ang)``.

    Rows of ``A``: 3 equalities ``W_lin f = F_lin``, 4 pyramid rows per point, then the
    bounds of every force component. The objective is divided by its mean diagonal (same
    minimiser) so that one ADMM penalty suits all configurations.
    """
    n = points.shape[0]
    dtype = points.dtype
    s = params.force_scale
    w_ang = jnp.concatenate([se3.hat(points[i] - com) for i in range(n)], axis=1)  # (3, 3n)
    diag = jnp.tile(
        jnp.asarray(
            [params.weight_tangential, params.weight_tangential, params.weight_normal], dtype
        ),
        n,
    )
    P = 2.0 * (jnp.diag(diag) + params.weight_angular * w_ang.T @ w_ang)
    q = -2.0 * params.weight_angular * (w_ang.T @ f_ang) / s
    scale = jnp.trace(P) / P.shape[0]
    P, q = P / scale, q / scale

    # Friction pyramid: 4 rows per point, (+-fx or +-fy) - mu fz <= 0.
    pyramid_rows = jnp.asarray(
        [[1, 0, -1], [-1, 0, -1], [0, 1, -1], [0, -1, -1]], dtype
    ) * jnp.asarray([1.0, 1.0, mu], dtype)
    pyramid = jnp.kron(jnp.eye(n, dtype=dtype), pyramid_rows)  # (4n, 3n)
    lin = jnp.tile(jnp.eye(3, dtype=dtype), (1, n))  # W_lin (3, 3n)
    A = jnp.concatenate([lin, pyramid, jnp.eye(3 * n, dtype=dtype)], axis=0)

    fz_hi = jnp.full((n,), params.fz_max, dtype) if fz_max is None else jnp.asarray(fz_max, dtype)
    active = in_contact.astype(dtype)
    box_lo = jnp.stack(
        [-params.ft_max * active, -params.ft_max * active, params.fz_min * active], -1
    ).reshape(-1)
    box_hi = jnp.stack(
        [params.ft_max * active, params.ft_max * active, fz_hi * active], -1
    ).reshape(-1)
    # The equality rows take the very same numbers as both bounds: divided apart, XLA has
    # rounded the two copies differently (1e-8 relative), the rows then failed the solvers'
    # ``upper - lower < 1e-9`` equality test, and the polish, handling them as inequalities,
    # was rejected on most float32 problems (session 25).
    target = f_lin / s
    lower = jnp.concatenate([target, jnp.full((4 * n,), -_BIG / s, dtype), box_lo / s])
    # Points out of contact are pinned to zero by their bounds; their pyramid rows are left
    # free so that no two active constraints are redundant (the polish needs that).
    pyramid_hi = jnp.where(jnp.repeat(in_contact, 4), 0.0, _BIG / s)
    upper = jnp.concatenate([target, pyramid_hi.astype(dtype), box_hi / s])
    return P, q, A, lower, upper, w_ang


def zero_warm_start(num_points: int, dtype=None) -> tuple:
    """The ``warm_start`` of a first solve: zero ADMM states for both cones (the QP has
    ``3 n`` variables and ``7 n + 3`` rows for ``n`` contact points)."""
    zero = admm.zero_state(3 * num_points, 7 * num_points + 3, dtype)
    return (zero, zero)


def constraint_ops(n: int, mu):
    """``(x -> A x, y -> A' y)`` for :func:`build_qp`'s ``A`` without forming it: the
    sum of the forces, 4 pyramid rows per point and the identity of the bounds, O(n)
    instead of the dense (7n + 3) x 3n products."""

    def a_mul(x):
        f = x.reshape(n, 3)
        fx, fy, mfz = f[:, 0], f[:, 1], mu * f[:, 2]
        pyramid = jnp.stack([fx - mfz, -fx - mfz, fy - mfz, -fy - mfz], axis=1)
        return jnp.concatenate([jnp.sum(f, axis=0), pyramid.reshape(-1), x])

    def at_mul(y):
        lin, pyr, box = y[:3], y[3 : 3 + 4 * n].reshape(n, 4), y[3 + 4 * n :]
        per_point = jnp.stack(
            [pyr[:, 0] - pyr[:, 1], pyr[:, 2] - pyr[:, 3], -mu * jnp.sum(pyr, axis=1)], axis=1
        )
        return (per_point + lin).reshape(-1) + box

    return a_mul, at_mul


def _solve(points, in_contact, com, f_lin, f_ang, mu, params, fz_max, warm):
    P, q, A, lower, upper, w_ang = build_qp(
        points, in_contact, com, f_lin, f_ang, mu, params, fz_max
    )
    result = admm.solve_qp(
        P,
        q,
        A,
        lower,
        upper,
        params.iterations,
        params.rho,
        adapt_every=params.adapt_every,
        warm_start=warm,
        unroll=params.unroll,
        a_ops=constraint_ops(points.shape[0], mu),
    )
    if params.polish:
        # Accept an exact KKT point that meets the constraints to within half the tolerance
        # that decides relaxation, even where ADMM's rounder iterate met them more closely.
        floor = 0.5 * params.tolerance / params.force_scale
        result = admm.polish(
            P, q, A, lower, upper, result, steps=params.polish_steps, violation_floor=floor
        )
    s = params.force_scale
    # Points out of contact are bound to zero: return exact zeros, not ADMM's ~1e-13.
    f = result.x * s * jnp.repeat(in_contact.astype(points.dtype), 3)
    lin_res = jnp.max(jnp.abs(jnp.sum(f.reshape(-1, 3), axis=0) - f_lin))
    # Cone and bounds, in newtons, on the forces themselves (not ADMM's internal copies).
    af = A[3:] @ f
    lo, hi = lower[3:] * s, upper[3:] * s
    violation = jnp.maximum(jnp.max(jnp.maximum(af - hi, lo - af)), 0.0)
    return (
        f.reshape(-1, 3),
        w_ang @ f,
        lin_res,
        jnp.maximum(violation, lin_res),
        result.dual_residual,
        result.state,
    )


def _relaxed_where_needed(params: ForceQPParams):
    """``f(need, points, in_contact, com, f_lin, f_ang, fz_max, warm)``: :func:`_solve` with
    ``mu_relaxed`` where ``need``, else zeros and ``warm`` unchanged.

    One robot: a ``lax.cond``. Under ``vmap`` (a custom batching rule, since ``vmap`` would
    turn the ``cond`` into a ``select`` that solves every problem): nothing when no problem
    needs it, the needing ones gathered into ``relaxed_slots`` slots when they fit, the
    whole batch otherwise. Every branch solves each problem by the same per-problem program,
    so a robot's result does not depend on which branch its batch took.
    """

    def solve(points, in_contact, com, f_lin, f_ang, fz_max, warm):
        mu = jnp.asarray(params.mu_relaxed, points.dtype)
        return _solve(points, in_contact, com, f_lin, f_ang, mu, params, fz_max, warm)

    def skipped(points, warm):
        zero = jnp.zeros((), points.dtype)
        return (jnp.zeros_like(points), jnp.zeros(3, points.dtype), zero, zero, zero, warm)

    @custom_vmap
    def relaxed(need, points, in_contact, com, f_lin, f_ang, fz_max, warm):
        args = (points, in_contact, com, f_lin, f_ang, fz_max, warm)
        return jax.lax.cond(need, solve, lambda *a: skipped(a[0], a[-1]), *args)

    @relaxed.def_vmap
    def relaxed_batched(axis_size, in_batched, need, *args):
        need_batched, *args_batched = in_batched
        need = need if need_batched else jnp.broadcast_to(need, (axis_size,))
        args = tuple(
            jax.tree.map(
                lambda a, b: a if b else jnp.broadcast_to(a, (axis_size, *jnp.shape(a))), x, xb
            )
            for x, xb in zip(args, args_batched, strict=True)
        )
        slots = min(params.relaxed_slots, axis_size)
        none = jax.vmap(skipped)(args[0], args[-1])

        def gathered():
            count = jnp.sum(need)
            (idx,) = jnp.nonzero(need, size=slots, fill_value=0)
            sub = jax.tree.map(lambda a: a[idx], args)
            out = jax.vmap(solve)(*sub)
            # Unused slots scatter out of range and are dropped.
            dest = jnp.where(jnp.arange(slots) < count, idx, axis_size)
            return jax.tree.map(lambda base, o: base.at[dest].set(o, mode="drop"), none, out)

        def whole():
            out = jax.vmap(solve)(*args)
            return jax.tree.map(
                lambda o, base: jnp.where(need.reshape((-1,) + (1,) * (o.ndim - 1)), o, base),
                out,
                none,
            )

        count = jnp.sum(need)
        branch = jnp.where(count == 0, 0, jnp.where(count <= slots, 1, 2))
        out = jax.lax.switch(branch, (lambda: none, gathered, whole))
        return out, jax.tree.map(lambda _: True, out)

    return relaxed


def solve_contact_forces(
    points,
    in_contact,
    com,
    f_lin,
    f_ang,
    params: ForceQPParams = ForceQPParams(),
    fz_max=None,
    warm_start=None,
) -> ForceQPSolution:
    """Contact forces for a desired CoM force ``f_lin = m (a_com + g)`` and CAM rate ``f_ang``.

    ``points`` (n, 3) world contact points, ``in_contact`` (n,) bool, ``com`` (3,).
    ``fz_max``: optional per-point upper normal-force bound (contact blending).
    ``warm_start``: the previous solution's ``warm_start``.
    """
    points, com = jnp.asarray(points), jnp.asarray(com)
    f_lin, f_ang = jnp.asarray(f_lin, points.dtype), jnp.asarray(f_ang, points.dtype)
    if warm_start is None:
        warm_start = zero_warm_start(points.shape[0], points.dtype)
    if params.relaxed_on_demand:
        n = points.shape[0]
        fz = jnp.full((n,), params.fz_max, points.dtype) if fz_max is None else fz_max
        fz = jnp.asarray(fz, points.dtype)
        mu = jnp.asarray(params.mu, points.dtype)
        nominal = _solve(points, in_contact, com, f_lin, f_ang, mu, params, fz, warm_start[0])
        use_relaxed = nominal[3] > params.tolerance
        relaxed = _relaxed_where_needed(params)(
            use_relaxed, points, in_contact, com, f_lin, f_ang, fz, warm_start[1]
        )
        relaxed_warm = jax.tree.map(
            lambda r, m: jnp.where(use_relaxed, r, m), relaxed[5], nominal[5]
        )
        warm_out = (nominal[5], relaxed_warm)
    else:
        # Both cones at once, as a batch of two: one pass of small ops instead of two.
        warm = jax.tree.map(lambda a, b: jnp.stack([a, b]), *warm_start)
        mus = jnp.asarray([params.mu, params.mu_relaxed], points.dtype)
        both = jax.vmap(
            lambda mu, w: _solve(points, in_contact, com, f_lin, f_ang, mu, params, fz_max, w)
        )(mus, warm)
        nominal, relaxed = (jax.tree.map(lambda a, k=k: a[k], both) for k in (0, 1))
        use_relaxed = nominal[3] > params.tolerance
        warm_out = (nominal[5], relaxed[5])
    pick = jax.tree.map(lambda a, b: jnp.where(use_relaxed, b, a), nominal[:5], relaxed[:5])
    forces, angular, lin_res, violation, dual = pick
    return ForceQPSolution(forces, angular, lin_res, violation, dual, use_relaxed, warm_out)
