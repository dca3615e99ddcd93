"""Gaussian radial-basis features on a regular grid over the apex state (Eq. 1), evaluated
with local support.

The paper's networks use 18 x 30 x 56 = 30,240 Gaussians with centres on a 0.02 grid and
``sigma = 0.02``, plus a bias. Evaluating all of them per state is wasteful: a Gaussian is
separable, ``phi_c(s) = prod_d exp(-(s_d - c_d)^2 / (2 sigma^2))``, and at more than a few
sigma it is negligible. So each state touches only the ``(2r + 1)^3`` centres nearest to it
(``r`` = ``radius`` cells per side): three 1-D weight vectors and one block of the weight
table. The cost per state is independent of the grid size. Truncation error: the nearest
dropped centre is at least ``(r + 1/2)`` spacings away along some axis, so (with
``sigma`` = spacing) every dropped feature is below ``exp(-(r + 1/2)^2 / 2)``: 4.4e-2 for
r = 2, 2.2e-3 for r = 3, 4.0e-5 for r = 4 (tests measure the total against dense
evaluation).

The weight table is stored zero-padded by ``radius`` cells on each side so a window never
leaves it; padding cells get zero feature weight, so they never contribute and never learn
(the network is exactly the grid's centres plus a bias).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxloco import validation as v


@dataclasses.dataclass(frozen=True)
class RBFGrid:
    """A regular grid of Gaussian centres over the apex state box (Eq. 1 by default)."""

    low: tuple[float, float, float] = (-0.14, 0.03, -0.55)
    """Lowest centre on each axis (y, xd, yd)."""
    counts: tuple[int, int, int] = (18, 30, 56)
    """Centres on each axis (y, xd, yd)."""
    spacing: float = 0.02
    """Distance between neighbouring centres on every axis (m, m/s)."""
    sigma: float = 0.02
    """The Gaussians' width (same units)."""
    radius: int = 3
    """Cells each side of the nearest centre that a state's features cover."""

    def __post_init__(self):
        v.check_fields(
            self,
            [
                ("low", len(self.low) == 3, "3 numbers (y, xd, yd)"),
                ("counts", len(self.counts) == 3, "3 numbers (y, xd, yd)"),
                ("counts", all(int(n) == n and n >= 1 for n in self.counts), "ints >= 1"),
                *(
                    (n, isinstance(getattr(self, n), (int, float)) and getattr(self, n) > 0, "> 0")
                    for n in ("spacing", "sigma")
                ),
                v.integer(self, "radius", 0),
            ],
        )

    @property
    def high(self) -> tuple[float, ...]:
        """Highest centre on each axis."""
        pairs = zip(self.low, self.counts, strict=True)
        return tuple(lo + (n - 1) * self.spacing for lo, n in pairs)

    @property
    def num_centres(self) -> int:
        return int(np.prod(self.counts))

    @property
    def window(self) -> int:
        return 2 * self.radius + 1

    @property
    def table_shape(self) -> tuple[int, int, int]:
        """Shape of the zero-padded weight table (without the output axis)."""
        return tuple(n + 2 * self.radius for n in self.counts)

    def truncation_bound(self) -> float:
        """Upper bound on any single dropped feature (see the module docstring)."""
        return math.exp(-0.5 * ((self.radius + 0.5) * self.spacing / self.sigma) ** 2)


@struct.dataclass
class LocalFeatures:
    """The non-zero features of one state: a window of the padded table.

    ``corner``: (3,) int, the window's first cell in padded-table coordinates.
    ``axis_weights``: (3, 2r + 1) per-axis Gaussian factors (zero on padding cells); the
    window's features are their outer product.
    """

    corner: jax.Array
    """(3,) int, the window's first cell in padded-table coordinates."""
    axis_weights: jax.Array
    """(3, 2r + 1) per-axis Gaussian factors (zero on padding cells)."""


def local_features(grid: RBFGrid, state) -> LocalFeatures:
    """Features of one apex state ``(3,)`` (vmap for batches)."""
    state = jnp.asarray(state)
    low = jnp.asarray(grid.low, state.dtype)
    counts = jnp.asarray(grid.counts)
    r = grid.radius
    # Nearest centre per axis, clamped to the grid so the window stays inside the padded
    # table (a state further out gets the edge window, whose features are then tiny).
    nearest = jnp.round((state - low) / grid.spacing).astype(jnp.int32)
    nearest = jnp.clip(nearest, 0, counts - 1)
    offsets = jnp.arange(-r, r + 1)
    cells = nearest[:, None] + offsets[None, :]  # (3, 2r+1) grid indices, maybe off-grid
    centres = low[:, None] + cells.astype(state.dtype) * grid.spacing
    weights = jnp.exp(-0.5 * ((state[:, None] - centres) / grid.sigma) ** 2)
    on_grid = (cells >= 0) & (cells < counts[:, None])
    return LocalFeatures(
        # The window starts r cells before the nearest centre; padded index = grid index + r.
        corner=nearest,
        axis_weights=jnp.where(on_grid, weights, 0.0),
    )


def evaluate(table, bias, features: LocalFeatures):
    """Linear read-out ``bias + sum_c table[c] phi_c(s)`` over the window: shape (outputs,)."""
    w = features.axis_weights.shape[1]
    block = jax.lax.dynamic_slice(table, (*features.corner, 0), (w, w, w, table.shape[-1]))
    a, b, c = features.axis_weights
    return bias + jnp.einsum("i,j,k,ijko->o", a, b, c, block)


def scatter_add(table, features: LocalFeatures, coefficients):
    """``table += outer(phi(s), coefficients)`` over each state's window.

    ``features`` batched over a leading axis (B,), ``coefficients`` (B, outputs). One
    scatter of ``B (2r+1)^3`` rows; rows of different states may coincide (they add).
    """
    a, b, c = (features.axis_weights[:, d] for d in range(3))  # (B, w) each
    w = a.shape[-1]
    phi = a[:, :, None, None] * b[:, None, :, None] * c[:, None, None, :]  # (B, w, w, w)
    offsets = jnp.arange(w)
    shape = table.shape[:3]
    i = features.corner[:, 0, None] + offsets[None, :]
    j = features.corner[:, 1, None] + offsets[None, :]
    k = features.corner[:, 2, None] + offsets[None, :]
    flat = (
        i[:, :, None, None] * (shape[1] * shape[2])
        + j[:, None, :, None] * shape[2]
        + k[:, None, None, :]
    ).reshape(-1)
    values = (phi[..., None] * coefficients[:, None, None, None, :]).reshape(-1, table.shape[-1])
    flat_table = table.reshape(-1, table.shape[-1]).at[flat].add(values)
    return flat_table.reshape(table.shape)


def dense_features(grid: RBFGrid, state) -> jax.Array:
    """All ``num_centres`` features of one state, no truncation (for tests and references)."""
    axes = [lo + grid.spacing * jnp.arange(n) for lo, n in zip(grid.low, grid.counts, strict=True)]
    per_axis = [jnp.exp(-0.5 * ((state[d] - axes[d]) / grid.sigma) ** 2) for d in range(3)]
    return jnp.einsum("i,j,k->ijk", *per_axis).reshape(-1)


def unpad(grid: RBFGrid, table):
    """The padded table's centre cells, ``(counts..., outputs)``."""
    r = grid.radius
    return table[r : table.shape[0] - r, r : table.shape[1] - r, r : table.shape[2] - r]
