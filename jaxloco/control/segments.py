"""Named pieces of one array: per-task or per-level vectors of different lengths, kept as
one array so a jitted call returns one buffer instead of one per piece (each output
buffer costs ~1.5 us of dispatch)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class Segments:
    """Vectors of static lengths ``sizes`` stacked along the last axis of ``values``.

    ``segments["com"]`` (by name) or ``segments[2]`` (by position) is the piece, with any
    leading (batch, time) axes of ``values`` kept.
    """

    values: jax.Array
    """(..., sum(sizes)) the pieces, in order."""
    names: tuple[str, ...] = struct.field(pytree_node=False)
    """The pieces' names, in order (static)."""
    sizes: tuple[int, ...] = struct.field(pytree_node=False)
    """Each piece's length, in order (static)."""

    @classmethod
    def stack(cls, pieces: dict[str, jax.Array]) -> Segments:
        """From ``{name: (..., size) array}`` (insertion order kept)."""
        names = tuple(pieces)
        sizes = tuple(int(jnp.shape(p)[-1]) for p in pieces.values())
        return cls(jnp.concatenate(list(pieces.values()), axis=-1), names, sizes)

    def __getitem__(self, key: str | int) -> jax.Array:
        if isinstance(key, str):
            if key not in self.names:
                raise KeyError(f"{key!r} is not one of {self.names}")
            key = self.names.index(key)
        if not -len(self.sizes) <= key < len(self.sizes):
            raise IndexError(f"segment {key} of {len(self.sizes)}")
        key %= len(self.sizes)
        start = sum(self.sizes[:key])
        return self.values[..., start : start + self.sizes[key]]

    def __len__(self) -> int:
        return len(self.sizes)

    def keys(self) -> tuple[str, ...]:
        return self.names

    def as_dict(self) -> dict[str, jax.Array]:
        return {name: self[name] for name in self.names}
