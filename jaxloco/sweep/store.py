"""A sweep on disk: a manifest, the push table, and one results file per chunk.

Layout of a run directory::

    manifest.json        spec, resolved config, chunking, backend, device, timings
    pushes.npz           the push table (one row per push)
    chunks/00012.npz     outcomes of rows [12 * chunk_size, 13 * chunk_size)
    walks/1.0_0.0_1.npz  snapshots of the undisturbed walk at apex speed 1.0, turn 0 deg,
                         replanning on (every phase the push table asks of it)

Chunk files are written to a temporary name and renamed, so a chunk file is either whole
or absent: an interrupted sweep loses at most the chunk in flight, and running the same
command again skips every chunk already on disk. A run directory belongs to one spec
(its digest is in the manifest); pointing a different sweep at it is an error.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from jaxloco.runtime import to_jsonable
from jaxloco.sweep.outcome import FIELDS
from jaxloco.sweep.spec import PushTable

# What must match for a run directory to be resumed: outcomes of chunks already written
# depend on every one of these (the backends, too, part ways after hard pushes).
_SAME_SWEEP_KEYS = (
    "spec_digest",
    "chunk_size",
    "num_pushes",
    "gait",
    "physics",
    "backend",
    "wblc_com_acc_limit",
    "wblc_force_qp",
    "wblc_hierarchy",
)


class SweepStore:
    """``writer=False`` reads but never writes (the other processes of a multi-host run:
    only process 0 writes)."""

    def __init__(self, run_dir: str | os.PathLike, writer: bool = True):
        self.dir = Path(run_dir)
        self.chunks_dir = self.dir / "chunks"
        self.writer = writer

    @property
    def manifest_path(self) -> Path:
        return self.dir / "manifest.json"

    def exists(self) -> bool:
        return self.manifest_path.exists()

    def read_manifest(self) -> dict:
        if not self.exists():
            raise FileNotFoundError(f"no sweep in {self.dir} (no manifest.json)")
        return json.loads(self.manifest_path.read_text())

    def write_manifest(self, manifest: dict) -> None:
        if not self.writer:
            return
        self.dir.mkdir(parents=True, exist_ok=True)
        tmp = self.manifest_path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(to_jsonable(manifest), indent=2) + "\n")
        os.replace(tmp, self.manifest_path)

    def open(self, manifest: dict, table: PushTable) -> dict:
        """Start a run, or resume the one already here when it is the same sweep.

        Returns the manifest in force (the existing one when resuming)."""
        if self.exists():
            old = self.read_manifest()
            for key in _SAME_SWEEP_KEYS:
                # Compare as stored (JSON: tuples become lists), so a resume matches itself.
                now = json.loads(json.dumps(to_jsonable(manifest.get(key))))
                if old.get(key) != now:
                    raise ValueError(
                        f"{self.dir} holds a different sweep ({key}: {old.get(key)!r} on disk, "
                        f"{now!r} now); choose another run directory"
                    )
            return old
        if not self.writer:
            return manifest
        self.chunks_dir.mkdir(parents=True, exist_ok=True)
        (self.dir / "walks").mkdir(exist_ok=True)
        np.savez(self.dir / "pushes.npz", **table.columns)
        self.write_manifest(manifest)
        return manifest

    def chunk_path(self, index: int) -> Path:
        return self.chunks_dir / f"{index:05d}.npz"

    def done(self, index: int) -> bool:
        return self.chunk_path(index).exists()

    def write_chunk(self, index: int, rows: np.ndarray, outcome: dict) -> None:
        if not self.writer:
            return
        path = self.chunk_path(index)
        tmp = path.with_name(path.stem + ".tmp.npz")
        np.savez(tmp, rows=rows, **outcome)
        os.replace(tmp, path)

    def walk_path(self, key: tuple) -> Path:
        """Where the undisturbed walk ``(apex_speed, turn_deg, replan)`` is kept."""
        speed, turn, replan = key
        return self.dir / "walks" / f"{speed!r}_{turn!r}_{int(replan)}.npz"

    def load_table(self) -> PushTable:
        with np.load(self.dir / "pushes.npz") as f:
            return PushTable({k: f[k] for k in f.files})

    def load_results(self) -> tuple[PushTable, dict, np.ndarray]:
        """(push table, outcome columns, mask of rows with results) of what is on disk."""
        table = self.load_table()
        n = len(table)
        out = {}
        have = np.zeros(n, bool)
        for path in sorted(self.chunks_dir.glob("[0-9]*.npz")):
            with np.load(path) as f:
                rows = f["rows"]
                for k in FIELDS:
                    if k not in out:
                        out[k] = np.zeros(n, f[k].dtype)
                    out[k][rows] = f[k]
                have[rows] = True
        return table, out, have
