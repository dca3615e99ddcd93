"""Inverses of small lower-triangular matrices, for the tick's batched linear algebra.

On XLA:CPU a triangular solve is one LAPACK call per matrix of the batch, whose cost
at the tick's sizes (the 24 to 38 dofs of a humanoid, a 24-force QP) is mostly per call and
per column of the right-hand side, not arithmetic (docs/architecture.md, measured choices).
Split in 2 x 2 blocks, ``[[A, 0], [C, B]]^-1 = [[A^-1, 0], [-B^-1 C A^-1, B^-1]]``, the
inverse is two half-size inverses and two products, and the products are what XLA does
well; up to :data:`LEAF` rows the blocks go to LAPACK. The result is the same inverse to
float round-off (relative error 1e-7 in float32; tested against the triangular solve).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

LEAF = 16
"""Blocks of at most this many rows are inverted by LAPACK's triangular solve: the 24 to
38 rows of the WBLC's factors split into leaves of 8 to 12, the fastest, and a task's 12
or 14 whitened rows go in one call (docs/architecture.md, measured choices)."""


def lower_triangular_inverse(lower: jax.Array, leaf: int = LEAF) -> jax.Array:
    """``L^-1`` (n, n) of a lower-triangular ``L`` (n, n) with a non-zero diagonal, by
    recursive 2 x 2 blocks (module doc). Batch it with ``vmap``."""
    n = lower.shape[-1]
    if lower.ndim != 2 or lower.shape[0] != n:
        raise ValueError(f"lower_triangular_inverse: need one (n, n) matrix, got {lower.shape}")
    if leaf < 1:
        raise ValueError(f"lower_triangular_inverse: leaf must be >= 1, got {leaf}")
    if n <= leaf:
        eye = jnp.eye(n, dtype=lower.dtype)
        return jax.scipy.linalg.solve_triangular(lower, eye, lower=True)
    h = n // 2
    top = lower_triangular_inverse(lower[:h, :h], leaf)
    bottom = lower_triangular_inverse(lower[h:, h:], leaf)
    coupling = -(bottom @ (lower[h:, :h] @ top))
    zeros = jnp.zeros((h, n - h), lower.dtype)
    return jnp.block([[top, zeros], [coupling, bottom]])
