"""A sweep on disk: a manifest, the push table, and one results file per chunk.

Layout of a run directory::

    manifest.json        spec, resolved config, chunking, backend, device, timings
    pushes.npz           the push table (one row per push)
    chunks/00012.npz     outcomes of rows [12 * chunk_size, 13 * chunk_size)
    walks/1.0_0.0_1.npz  snapshots of the undisturbed walk at apex speed 1.0, turn 0 deg,
                         replanning on (every phase the push table asks of it; the
                         walks may be kept elsewhere, ``SweepJob.walks_dir``)

Chunk files are written to a temporary name and renamed, so a chunk file is either whole
or absent: an interrupted sweep loses at most the chunk in flight, and running the same
command again skips every chunk already on disk. Each chunk file carries a SHA-256 of its
rows and outcomes; a file that does not read back whole, or whose content does not match
its digest or its rows, is moved aside (``chunks/NNNNN.corrupt.npz``) and its chunk runs
again. A run directory belongs to one sweep (its push table and settings are in the
manifest); pointing a different sweep at it is an error.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import zipfile
from pathlib import Path

import numpy as np

from jaxloco.runtime import to_jsonable
from jaxloco.sweep.outcome import FIELDS
from jaxloco.sweep.spec import PushTable

log = logging.getLogger(__name__)

# What must match for a run directory to be resumed: outcomes of chunks already written
# depend on every one of these (the backends, too, part ways after hard pushes).
_SAME_SWEEP_KEYS = ("table_digest", "num_pushes", "settings")


def table_digest(table: PushTable) -> str:
    """A short hash of every column of a push table (names, dtypes and values)."""
    h = hashlib.sha256()
    for name in sorted(table.columns):
        col = np.ascontiguousarray(table.columns[name])
        h.update(f"{name}:{col.dtype.str}:{col.shape}".encode())
        h.update(col.tobytes())
    return h.hexdigest()[:16]


def _content_digest(rows: np.ndarray, outcome: dict) -> str:
    h = hashlib.sha256(np.ascontiguousarray(rows).tobytes())
    for name in sorted(outcome):
        col = np.ascontiguousarray(outcome[name])
        h.update(f"{name}:{col.dtype.str}:{col.shape}".encode())
        h.update(col.tobytes())
    return h.hexdigest()


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
        """Start a run, or resume the one already here when it is the same sweep
        (``manifest`` must hold the keys :data:`_SAME_SWEEP_KEYS`, ``table_digest`` being
        :func:`table_digest` of ``table``).

        Returns the manifest in force (the existing one when resuming)."""
        if not self.exists() and any(self.chunks_dir.glob("*.npz")):
            raise ValueError(
                f"{self.dir} holds chunk files but no manifest.json: they belong to no known "
                "sweep; choose another run directory"
            )
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
        np.savez(self.dir / "pushes.npz", **table.columns)
        self.write_manifest(manifest)
        return manifest

    def chunk_path(self, index: int) -> Path:
        return self.chunks_dir / f"{index:05d}.npz"

    def read_chunk(self, index: int, rows: np.ndarray | None = None) -> dict | None:
        """The outcome columns of chunk ``index`` (and its ``rows``), or None when the
        chunk has no intact file: absent, unreadable, not matching its digest, or (given
        ``rows``) not holding those rows. A damaged file is moved aside, so the chunk is
        run again."""
        path = self.chunk_path(index)
        if not path.exists():
            return None
        try:
            with np.load(path) as f:
                data = {k: f[k] for k in f.files}
            stored = str(data.pop("digest"))
            got_rows = data.pop("rows")
            ok = (
                stored == _content_digest(got_rows, data)
                and set(data) == set(FIELDS)
                and all(len(data[k]) == len(got_rows) for k in FIELDS)
                and (rows is None or np.array_equal(got_rows, rows))
            )
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as err:
            ok, reason = False, f"{type(err).__name__}: {err}"
        else:
            reason = "its content does not match its digest or its rows"
        if not ok:
            log.warning("chunk file %s is damaged (%s); its chunk runs again", path, reason)
            if self.writer:
                os.replace(path, path.with_name(path.stem + ".corrupt.npz"))
            return None
        return {"rows": got_rows, **data}

    def done(self, index: int, rows: np.ndarray | None = None) -> bool:
        """Whether chunk ``index`` has an intact file (see :meth:`read_chunk`)."""
        return self.read_chunk(index, rows) is not None

    def write_chunk(self, index: int, rows: np.ndarray, outcome: dict) -> None:
        if not self.writer:
            return
        path = self.chunk_path(index)
        tmp = path.with_name(f"{path.stem}.tmp{os.getpid()}.npz")
        np.savez(tmp, rows=rows, digest=_content_digest(rows, outcome), **outcome)
        os.replace(tmp, path)

    def load_table(self) -> PushTable:
        with np.load(self.dir / "pushes.npz") as f:
            return PushTable({k: f[k] for k in f.files})

    def load_results(self) -> tuple[PushTable, dict, np.ndarray]:
        """(push table, outcome columns, mask of rows with results) of what is on disk."""
        table = self.load_table()
        n = len(table)
        out = {}
        have = np.zeros(n, bool)
        for path in sorted(self.chunks_dir.glob("[0-9][0-9][0-9][0-9][0-9].npz")):
            chunk = self.read_chunk(int(path.stem))
            if chunk is None:
                continue
            rows = chunk["rows"]
            for k in FIELDS:
                if k not in out:
                    out[k] = np.zeros(n, chunk[k].dtype)
                out[k][rows] = chunk[k]
            have[rows] = True
        return table, out, have
