"""Pytrees packed into one flat array per dtype, and host arrays into one buffer.

Each array passed to (or returned from) a jitted call is converted on its own, at a few
microseconds each; a controller's state and log have dozens of leaves. A closed loop that
calls the controller every millisecond therefore passes them packed: :class:`TreeLayout`
flattens a pytree into one array per dtype and back inside the program, and
:class:`HostGather` copies MuJoCo's live fields into one contiguous buffer on the host.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np


@dataclasses.dataclass(frozen=True)
class TreeLayout:
    """Where each leaf of a pytree lives when the tree is packed into one flat array per
    dtype (static: shapes, dtypes and structure; hashable, so it can key a compile cache).

    Not ``jax.flatten_util.ravel_pytree``: that casts every leaf to one common dtype, and
    the outcome's integer counters and boolean flags keep their own here."""

    treedef: jax.tree_util.PyTreeDef
    """The pytree's structure."""
    shapes: tuple[tuple[int, ...], ...]
    """Each leaf's shape, in leaf order."""
    dtypes: tuple[str, ...]
    """Each leaf's dtype name, in leaf order."""

    @classmethod
    def of(cls, tree) -> TreeLayout:
        leaves, treedef = jax.tree.flatten(tree)
        return cls(
            treedef,
            tuple(tuple(x.shape) if hasattr(x, "shape") else np.shape(x) for x in leaves),
            tuple(np.dtype(x.dtype).name for x in leaves),
        )

    def describe(self) -> str:
        """The structure with each leaf's dtype and shape, for error messages."""
        leaves = [f"{d}{list(s)}" for d, s in zip(self.dtypes, self.shapes, strict=True)]
        return str(jax.tree.unflatten(self.treedef, leaves))

    def _groups(self):
        groups = {}
        for k, dtype in enumerate(self.dtypes):
            groups.setdefault(dtype, []).append(k)
        return groups

    def pack(self, tree, xp=jnp) -> dict:
        """``{dtype name: (size,) array}`` of the tree's leaves, raveled in leaf order;
        ``xp=numpy`` packs on the host (no JAX dispatch per leaf)."""
        leaves = jax.tree.leaves(tree)
        return {
            dtype: xp.concatenate([xp.ravel(xp.asarray(leaves[k], dtype)) for k in ids])
            for dtype, ids in self._groups().items()
        }

    def unpack(self, packed: dict):
        """The tree back from :meth:`pack`'s arrays; arrays with leading axes (e.g. ``(T,
        size)``, one packed row per tick) give leaves with the same leading axes. Numpy
        arrays give numpy views."""
        leaves = [None] * len(self.shapes)
        for dtype, ids in self._groups().items():
            flat = packed[dtype]
            lead = tuple(flat.shape[:-1])
            offset = 0
            for k in ids:
                size = int(np.prod(self.shapes[k], dtype=int))
                leaves[k] = flat[..., offset : offset + size].reshape(lead + self.shapes[k])
                offset += size
        return jax.tree.unflatten(self.treedef, leaves)

    def sizes(self) -> dict:
        """``{dtype name: size}`` of :meth:`pack`'s arrays."""
        return {
            dtype: sum(int(np.prod(self.shapes[k], dtype=int)) for k in ids)
            for dtype, ids in self._groups().items()
        }


class HostGather:
    """Copies a tuple of host arrays (leading axis: robots) into one contiguous ``(n,
    size)`` float64 buffer, in :class:`TreeLayout` order, so a tick passes them to the
    jitted controller as one array instead of converting each of MuJoCo's bound fields on
    its own (docs/architecture.md, measured choices). Two buffers alternate, so
    the one a tick reads is never rewritten while that tick may still run."""

    def __init__(self, arrays: tuple):
        self.arrays = arrays
        n = len(arrays[0])
        self.layout = TreeLayout.of(tuple(np.zeros(a.shape[1:], np.float64) for a in arrays))
        sizes = [int(np.prod(a.shape[1:], dtype=int)) for a in arrays]
        total = sum(sizes)
        self._buffers = [np.zeros((n, total)), np.zeros((n, total))]
        offsets = np.cumsum([0, *sizes])
        # Views of each buffer shaped like each array: one copy per field, no temporaries.
        self._views = [
            [
                buf[:, lo:hi].reshape(a.shape)
                for a, lo, hi in zip(arrays, offsets[:-1], offsets[1:], strict=True)
            ]
            for buf in self._buffers
        ]
        self._next = 0

    def gather(self) -> np.ndarray:
        """The arrays' current values, packed: ``(n, size)``."""
        views = self._views[self._next]
        for view, array in zip(views, self.arrays, strict=True):
            np.copyto(view, array)
        buf = self._buffers[self._next]
        self._next = 1 - self._next
        return buf

    def unpack(self, row) -> tuple:
        """Inside the jitted (vmapped) tick: one robot's row back into the arrays."""
        return self.layout.unpack({"float64": row})
