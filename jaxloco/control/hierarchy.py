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
special cases. Each task's rows are first whitened (:func:`whiten_task`), so the rank
threshold reads as "the fraction of a task direction left free by the levels above",
whatever the units of its rows. The levels are a Python sequence of static shapes: the
loop unrolls at trace time and the result batches with ``vmap``.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
from flax import struct

from jaxloco.control.pinv import pinv_psd


@struct.dataclass
class HierarchyResult:
    qdd: jax.Array
    """``qdd_[task]`` (nv,), Eq. 9."""
    null_space: jax.Array
    """``N_{n|prec(n)}`` (nv, nv), Eq. 13: the motions that leave every task unchanged."""
    task_residuals: tuple
    """Per level, ``e_k - J_k qdd_[task]``: what the level could not achieve (0 if met)."""


def dynamically_consistent_inverse(jacobian, mass_inv, rtol: float = 1e-8, scale=None):
    """``Jbar = A^-1 J' (J A^-1 J')^+`` (Eq. 7); ``scale``: see :func:`pinv_psd`."""
    a_inv_jt = mass_inv @ jacobian.T
    return a_inv_jt @ pinv_psd(jacobian @ a_inv_jt, rtol, scale)


def whiten_task(jacobian, command, mass_inv):
    """Rows ``L^-1 J`` and command ``L^-1 e`` with ``L L' = J A^-1 J'`` (plus a jitter of
    100 machine epsilons of its largest diagonal entry, so rows switched off stay zero).

    An invertible change of a task's rows leaves its solution unchanged; what it changes
    is which directions a rank threshold calls lost. Task rows mix units (a foot's rotation
    and translation, joints with light and heavy links), so without it the eigenvalues of a
    single task span 1e-4..1 of its largest before any projection, and a relative threshold
    drops directions that are not lost: at ``rtol = 1e-3`` the two-foot contact constraint
    lost 4 of its 12 directions at the walking keyframe.
    """
    gram = (jacobian @ mass_inv) @ jacobian.T
    dtype = gram.dtype
    largest = jnp.max(jnp.diagonal(gram))
    jitter = jnp.where(largest > 0, 100.0 * jnp.finfo(dtype).eps * largest, 1.0)
    chol = jnp.linalg.cholesky(gram + jitter * jnp.eye(gram.shape[0], dtype=dtype))
    solve = functools.partial(jax.scipy.linalg.solve_triangular, chol, lower=True)
    return solve(jacobian), solve(command)


def prioritized_accelerations(
    jacobians: Sequence[jax.Array],
    commands: Sequence[jax.Array],
    mass_inv: jax.Array,
    rtol: float = 1e-8,
    whiten: bool = True,
) -> HierarchyResult:
    """Joint accelerations for tasks in priority order (first = highest), Eq. 9-10.

    ``jacobians[k]`` is ``(m_k, nv)``; ``commands[k]`` is ``e_k = xdd_k^d - Jdot_k qd``,
    ``(m_k,)`` or ``(m_k, r)``: the map is linear in the commands, so ``r`` columns of
    commands give ``r`` columns of ``qdd`` and residuals from one pass.
    ``whiten``: threshold each level in whitened rows (:func:`whiten_task`, ``rtol`` is then
    the fraction of a task direction left free); ``False`` thresholds relative to the
    unprojected task's largest diagonal entry of ``J A^-1 J'``, in the units of its rows.
    """
    if len(jacobians) != len(commands) or not jacobians:
        raise ValueError("prioritized_accelerations: need one command per Jacobian, >= 1 task")
    nv = mass_inv.shape[0]
    eye = jnp.eye(nv, dtype=mass_inv.dtype)
    null = eye
    qdd = jnp.zeros((nv, *jnp.shape(commands[0])[1:]), mass_inv.dtype)
    for jac, cmd in zip(jacobians, commands, strict=True):
        if whiten:
            jac_w, cmd_w = whiten_task(jac, cmd, mass_inv)
            # Whitened, the unprojected task's J A^-1 J' is I: each eigenvalue of the
            # projected one is the fraction of a task direction the levels above leave free.
            scale = jnp.ones((), qdd.dtype)
        else:
            jac_w, cmd_w = jac, cmd
            # Rank judged against the task's own size before projection (see pinv_psd).
            scale = jnp.max(jnp.sum((jac @ mass_inv) * jac, axis=1))
        projected = jac_w @ null  # J_{k|prec(k)}
        jbar = dynamically_consistent_inverse(projected, mass_inv, rtol, scale)
        qdd = qdd + jbar @ (cmd_w - jac_w @ qdd)
        null = null @ (eye - jbar @ projected)
    residuals = tuple(cmd - jac @ qdd for jac, cmd in zip(jacobians, commands, strict=True))
    return HierarchyResult(qdd, null, residuals)
