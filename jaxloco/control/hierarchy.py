"""The prioritised, dynamically consistent task hierarchy of WBLC (paper Eq. 6-10, 13).

For tasks ``k = 1..n`` with Jacobians ``J_k`` and commands ``e_k = xdd_k^d - Jdot_k qd``::

    qdd_1 = Jbar_1 e_1,                           Jbar = A^-1 J' (J A^-1 J')^+
    qdd_k = Jbar_{k|prec(k)} (e_k - J_k sum_{i<k} qdd_i)
    J_{k|prec(k)} = J_k N_prec(k),                N_prec(k) = N_1 N_{2|1} ... N_{k-1|k-2}
    N_{s|s-1} = I - Jbar_{s|prec(s)} J_{s|prec(s)}

and ``qdd_[task] = sum_k qdd_k`` (Eq. 9). The inverses are dynamically consistent
(Eq. 7): lower-priority accelerations are filtered through ``N_prec``, which leaves every
higher-priority task acceleration unchanged, in the metric of the mass matrix. The
``(J A^-1 J')^+`` are thresholded pseudo-inverses (:mod:`jaxloco.control.pinv`), so a
task that is redundant with the ones above it, or masked to zero rows, is handled without
special cases. With ``inverse="damped"`` (per level, or for all) they are damped
least-squares inverses instead (:func:`jaxloco.control.pinv.damped_pinv_psd`): a task
direction with freedom ``s`` (its whitened eigenvalue) is followed to a fraction
``s^2 / (s^2 + rtol^2)`` of its command, a lower task disturbs it by about
``(rtol/s)^2`` of what the lower task asks instead of not at all, and no command is
amplified by more than ``1/(2 rtol)``. Each task's rows are first whitened
(:func:`whiten_task`), so the rank
threshold reads as "the fraction of a task direction left free by the levels above",
whatever the units of its rows. The levels are a Python sequence of static shapes: the
loop unrolls at trace time and the result batches with ``vmap``.

**How it is computed.** With the mass matrix factored as ``A = L L'``, the coordinates
``y = L' qdd`` turn the mass-matrix metric into the Euclidean one: ``J A^-1 J' = Jt Jt'``
for ``Jt = J L^-T``, and the dynamically consistent null-space projectors become
orthogonal projectors ``P`` with ``N_prec = L^-T P L'``. Each level then costs products
of its ``m`` rows with an ``(nv, nv)`` projector (``P <- P - B' (B B')^+ B`` for
``B = Jt P``) instead of ``(nv, nv)`` by ``(nv, nv)`` products and a multiplication by
``A^-1`` per level; the matrices whose pseudo-inverses are taken are the same as in the
formulas above, so the thresholds decide the same way.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
from flax import struct

from jaxloco.control.pinv import damped_pinv_psd, pinv_psd
from jaxloco.control.triangular import lower_triangular_inverse

INVERSES = {"truncated": pinv_psd, "damped": damped_pinv_psd}
"""The per-level inverses of ``J A^-1 J'``: ``truncated`` (the paper's thresholded
pseudo-inverse, exact priorities) or ``damped`` (damped least squares, see
:func:`jaxloco.control.pinv.damped_pinv_psd`)."""


@struct.dataclass
class HierarchyResult:
    qdd: jax.Array
    """``qdd_[task]`` (nv,) or (nv, r), Eq. 9."""
    projector: jax.Array
    """(nv, nv) orthogonal projector ``P`` onto the motions, in ``y = L' qdd`` coordinates,
    that leave every task unchanged: ``N = L^-T P L'`` (see :attr:`null_space`). With the
    damped inverse, symmetric with eigenvalues in [0, 1] and idempotent to ``rtol^2``."""
    mass_cholesky: jax.Array
    """(nv, nv) lower-triangular ``L`` with ``A = L L'``."""
    mass_cholesky_inverse: jax.Array
    """(nv, nv) ``L^-1`` (lower triangular)."""
    task_residuals: tuple[jax.Array, ...]
    """Per level, ``e_k - J_k qdd_[task]``: what the level could not achieve (0 if met)."""

    @property
    def null_space(self) -> jax.Array:
        """``N_{n|prec(n)}`` (nv, nv), Eq. 13: the motions that leave every task unchanged."""
        return self.mass_cholesky_inverse.T @ (self.projector @ self.mass_cholesky.T)

    def apply_null_space(self, qdd_free: jax.Array) -> jax.Array:
        """``N qdd_free`` (nv,) without forming ``N``."""
        y = self.projector @ (self.mass_cholesky.T @ qdd_free)
        return self.mass_cholesky_inverse.T @ y

    def mass_times_null_space(self) -> jax.Array:
        """``A N = L P L'`` (nv, nv), the null-space columns of Eq. 17."""
        return (self.mass_cholesky @ self.projector) @ self.mass_cholesky.T


def whiten_task(jacobian, command):
    """Rows ``C^-1 J`` and command ``C^-1 e`` with ``C C' = J J'`` (plus a jitter of 100
    machine epsilons of its largest diagonal entry, so rows switched off stay zero), for
    rows ``J`` already in the coordinates where the metric is Euclidean (``Jt = J L^-T``,
    where ``J J'`` is the task's ``J A^-1 J'``).

    An invertible change of a task's rows leaves its solution unchanged; what it changes
    is which directions a rank threshold calls lost. Task rows mix units (a foot's rotation
    and translation, joints with light and heavy links), so without it the eigenvalues of a
    single task span 1e-4..1 of its largest before any projection, and a relative threshold
    drops directions that are not lost: at ``rtol = 1e-3`` the two-foot contact constraint
    lost 4 of its 12 directions at the walking keyframe.

    Batched over leading axes: ``jacobian`` ``(..., m, nv)``, ``command`` ``(..., m, r)``
    (or ``(m,)`` unbatched).
    """
    gram = jacobian @ jnp.swapaxes(jacobian, -1, -2)
    dtype = gram.dtype
    largest = jnp.max(jnp.diagonal(gram, axis1=-2, axis2=-1), axis=-1)[..., None, None]
    jitter = jnp.where(largest > 0, 100.0 * jnp.finfo(dtype).eps * largest, 1.0)
    gram = gram + jitter * jnp.eye(gram.shape[-1], dtype=dtype)
    vector = command.ndim == jacobian.ndim - 1
    rhs = command[..., None] if vector else command
    if gram.shape[-1] == 3:
        inverse = _cholesky_inverse3(gram)
    else:
        chol = jnp.linalg.cholesky(gram)
        # C^-1 once, then one product for the rows and the command: LAPACK's triangular
        # solve costs per column of its right-hand side, and the rows have nv + r columns.
        inverse = jnp.vectorize(lower_triangular_inverse, signature="(m,m)->(m,m)")(chol)
    solved = inverse @ jnp.concatenate([jacobian, rhs], axis=-1)
    whitened, command = solved[..., : jacobian.shape[-1]], solved[..., jacobian.shape[-1] :]
    return whitened, command[..., 0] if vector else command


def _cholesky_inverse3(gram):
    """``C^-1`` for the lower Cholesky factor ``C`` of symmetric positive definite 3 x 3
    matrices ``gram`` (batched over leading axes), in element-wise arithmetic: batched, XLA
    runs it as one fused loop, where LAPACK takes a factorisation and a triangular solve per
    matrix (the walking hierarchy whitens seven 3-row levels)."""
    g = {(i, j): gram[..., i, j] for i in range(3) for j in range(i + 1)}
    l00 = jnp.sqrt(g[0, 0])
    l10, l20 = g[1, 0] / l00, g[2, 0] / l00
    l11 = jnp.sqrt(g[1, 1] - l10 * l10)
    l21 = (g[2, 1] - l20 * l10) / l11
    l22 = jnp.sqrt(g[2, 2] - l20 * l20 - l21 * l21)
    i00, i11, i22 = 1.0 / l00, 1.0 / l11, 1.0 / l22
    i10 = -l10 * i00 * i11
    i21 = -l21 * i11 * i22
    i20 = -(l20 * i00 + l21 * i10) * i22
    zero = jnp.zeros_like(i00)
    rows = [(i00, zero, zero), (i10, i11, zero), (i20, i21, i22)]
    return jnp.stack([jnp.stack(row, -1) for row in rows], -2)


def prioritized_accelerations(
    jacobians: Sequence[jax.Array],
    commands: Sequence[jax.Array],
    mass_cholesky: jax.Array,
    rtol: float = 1e-8,
    whiten: bool = True,
    inverse: str | Sequence[str] = "truncated",
    mass_cholesky_inverse: jax.Array | None = None,
) -> HierarchyResult:
    """Joint accelerations for tasks in priority order (first = highest), Eq. 9-10.

    ``jacobians[k]`` is ``(m_k, nv)``; ``commands[k]`` is ``e_k = xdd_k^d - Jdot_k qd``,
    ``(m_k,)`` or ``(m_k, r)``: the map is linear in the commands, so ``r`` columns of
    commands give ``r`` columns of ``qdd`` and residuals from one pass.
    ``mass_cholesky``: lower-triangular ``L`` with ``L L' = A``, the mass matrix.
    ``whiten``: threshold each level in whitened rows (:func:`whiten_task`, ``rtol`` is then
    the fraction of a task direction left free); ``False`` thresholds relative to the
    unprojected task's largest diagonal entry of ``J A^-1 J'``, in the units of its rows.
    ``inverse``: ``"truncated"`` or ``"damped"`` (:data:`INVERSES`), for every level or
    one per level; with ``"damped"`` ``rtol`` is the damping and ``projector`` is only
    approximately idempotent.
    ``mass_cholesky_inverse``: ``L^-1`` when the caller has it (computed here otherwise).
    The coordinate changes are products with it: for a 34-dof robot, batched, the
    triangular solve of the stacked task rows cost more than inverting ``L`` once.
    """
    if len(jacobians) != len(commands) or not jacobians:
        raise ValueError("prioritized_accelerations: need one command per Jacobian, >= 1 task")
    inverses = (inverse,) * len(jacobians) if isinstance(inverse, str) else tuple(inverse)
    if len(inverses) != len(jacobians) or any(i not in INVERSES for i in inverses):
        raise ValueError(
            f"prioritized_accelerations: inverse must be one of {sorted(INVERSES)} or one "
            f"per level ({len(jacobians)}), got {inverse!r}"
        )
    chol = mass_cholesky
    nv = chol.shape[0]
    dtype = chol.dtype
    sizes = [j.shape[0] for j in jacobians]
    offsets = [sum(sizes[:k]) for k in range(len(sizes))]
    command_shape = jnp.shape(commands[0])[1:]
    cmds = [jnp.reshape(c, (c.shape[0], -1)).astype(dtype) for c in commands]  # (m_k, r)
    r = cmds[0].shape[1]
    chol_inv = (
        jax.scipy.linalg.solve_triangular(chol, jnp.eye(nv, dtype=dtype), lower=True)
        if mass_cholesky_inverse is None
        else mass_cholesky_inverse
    )
    stacked = jnp.concatenate(jacobians, axis=0) @ chol_inv.T  # Jt = J L^-T, every level
    levels = [(stacked[o : o + m], c) for o, m, c in zip(offsets, sizes, cmds, strict=True)]
    if whiten:
        # Levels of equal size are whitened together: one batched factorisation each.
        for m in sorted(set(sizes)):
            group = [k for k, size in enumerate(sizes) if size == m]
            rows, cmd = whiten_task(
                jnp.stack([levels[k][0] for k in group]), jnp.stack([levels[k][1] for k in group])
            )
            for i, k in enumerate(group):
                levels[k] = (rows[i], cmd[i])
    # State [y | P] (nv, r + nv): the accumulated solution in y = L' qdd coordinates and the
    # orthogonal projector onto what the levels so far leave free; one product per level
    # updates both. The first level sees y = 0 and P = I, so its products with them are
    # skipped (XLA does not fold a product with a constant identity).
    state = None
    for (rows, cmd), name, m in zip(levels, inverses, sizes, strict=True):
        if whiten:
            # Whitened, the unprojected task's J A^-1 J' is I: each eigenvalue of the
            # projected one is the fraction of a task direction the levels above leave free.
            scale = jnp.ones((), dtype)
        else:
            # Rank judged against the task's own size before projection (see pinv_psd).
            scale = jnp.max(jnp.sum(rows * rows, axis=1))
        if state is None:
            projected, unmet = rows, cmd  # J_{k|prec(k)} in y coordinates; e_k - Jt y
        else:
            both = rows @ state
            projected, unmet = both[:, r:], cmd - both[:, :r]
        gram_pinv = INVERSES[name](projected @ projected.T, rtol, scale)
        coeffs = gram_pinv @ jnp.concatenate([unmet, -projected], axis=1)  # (m, r + nv)
        if state is None:
            state = jnp.concatenate([jnp.zeros((nv, r), dtype), jnp.eye(nv, dtype=dtype)], axis=1)
        # The update projected' coeffs is a sum of m outer products: written element-wise,
        # XLA fuses it with the addition into one loop; as a product, XLA:CPU runs a small
        # batched GEMM and a separate addition (docs/architecture.md, measured choices).
        state = state + sum(projected[j][:, None] * coeffs[j][None, :] for j in range(m))
    y, projector = state[:, :r], state[:, r:]
    qdd = chol_inv.T @ y
    # Every level's residual from one product (one operation instead of one per level).
    stacked_residual = jnp.concatenate(cmds, axis=0) - jnp.concatenate(jacobians, axis=0) @ qdd
    residuals = tuple(
        stacked_residual[o : o + m].reshape((m, *command_shape))
        for o, m in zip(offsets, sizes, strict=True)
    )
    qdd = qdd.reshape((nv, *command_shape))
    return HierarchyResult(qdd, projector, chol, chol_inv, residuals)
