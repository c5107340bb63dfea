"""The files of a traces directory: `shard_<first>.npz` (the jobs of a block of consecutive
ids), `pending/job_<i>.npz` (a finished job not yet in a shard) and `manifest.json`; npz
files are written with fixed time stamps, so the same arrays give the same bytes, and checked
field by field when read (`shards.py`)."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from ngpm_runtime.files import atomic_write

from ngpm_compiler.learning.shards import (
    ShardError,
    TraceError,
    check_manifest,
    check_shard,
    read_npz,
)

TRACE_FORMAT = "ngpm-traces/1"


def save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """np.savez, but the same arrays give the same bytes (no time stamps in the zip)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
        for key, arr in arrays.items():
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            with zf.open(info, "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(arr), allow_pickle=False)
    atomic_write(path, buf.getvalue())


def load_npz(path: Path, widths: dict[int, int] | None = None) -> dict[str, np.ndarray]:
    """A shard's or pending job's arrays, checked (`shards.check_shard`)."""
    arrays = read_npz(path)
    check_shard(path, arrays, widths)
    return arrays


def merge_arrays(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    keys = sorted({k for p in parts for k in p})
    return {k: np.concatenate([p[k] for p in parts if k in p]) for k in keys}


class TraceStore:
    """The files of one traces directory; with `widths` (site index -> feature columns),
    shards whose sites or feature widths differ are refused."""

    def __init__(self, directory: str | Path, widths: dict[int, int] | None = None) -> None:
        self.dir = Path(directory)
        self.pending = self.dir / "pending"
        self.widths = widths

    def shard_paths(self) -> list[Path]:
        return sorted(self.dir.glob("shard_*.npz"))

    def pending_paths(self) -> list[Path]:
        return sorted(self.pending.glob("job_*.npz")) if self.pending.is_dir() else []

    def manifest(self) -> dict[str, Any] | None:
        """manifest.json, checked (`shards.check_manifest`); None when there is none."""
        path = self.dir / "manifest.json"
        if not path.is_file():
            return None
        try:
            manifest: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
        except ValueError:
            raise TraceError(f"{path}: corrupt manifest (not JSON)") from None
        check_manifest(path, manifest)
        return manifest

    def write_manifest(self, manifest: dict[str, Any]) -> None:
        atomic_write(self.dir / "manifest.json", json.dumps(manifest, indent=1).encode("utf-8"))

    def write_pending(self, arrays: dict[str, np.ndarray]) -> None:
        self.pending.mkdir(parents=True, exist_ok=True)
        save_npz(self.pending / f"job_{int(arrays['jobs'][0]):08d}.npz", arrays)

    def finished(self, unreadable: list[str] | None = None) -> dict[str, np.ndarray]:
        """Every finished job's arrays (shards, then pending), deduplicated by job id.
        With a list `unreadable`, shards that cannot be read or are malformed are skipped
        and named there (with the reason)."""
        parts = []
        where: dict[int, str] = {}  # job id -> the shard holding it
        for path in self.shard_paths():
            try:
                part = load_npz(path, self.widths)
            except ShardError as err:
                if unreadable is None:
                    raise
                unreadable.append(f"{path.name} ({err.reason})")
                continue
            for j in part["jobs"].tolist():
                if j in where:
                    raise TraceError(
                        f"{self.dir}: job {j} is in two shards, {where[j]} and "
                        f"{path.name}; remove one of them"
                    )
                where[j] = path.name
            parts.append(part)
        for path in self.pending_paths():
            part = load_npz(path, self.widths)
            if len(part["jobs"]) != 1 or f"job_{int(part['jobs'][0]):08d}.npz" != path.name:
                raise ShardError(path, "'jobs' does not hold the one job the file is named for")
            if int(part["jobs"][0]) not in where:  # else: already in a shard
                where[int(part["jobs"][0])] = path.name
                parts.append(part)
        if not parts:
            return {"jobs": np.zeros(0, np.int64), "kept": np.zeros(0, bool)}
        return merge_arrays(parts)

    def consolidate(self, done: set[int] | None = None, block: int = 1) -> None:
        """Gather pending jobs into new shards, then remove them: with `done` (every finished
        job id), one shard per block of `block` consecutive job ids that are all done, and
        the other pending jobs stay pending; without, all pending jobs into one shard."""
        groups: dict[int, list[Path]] = {}
        for p in self.pending_paths():
            job = int(p.stem.partition("_")[2])
            groups.setdefault(job // block if done is not None else 0, []).append(p)
        if done is not None:
            groups = {
                b: ps
                for b, ps in groups.items()
                if all(j in done for j in range(b * block, (b + 1) * block))
            }
        if not groups:
            return
        in_shards: set[int] = set()
        for p in self.shard_paths():
            in_shards.update(int(j) for j in load_npz(p)["jobs"])
        for paths in groups.values():
            parts = [a for a in (load_npz(p) for p in paths) if int(a["jobs"][0]) not in in_shards]
            if parts:
                merged = merge_arrays(parts)
                save_npz(self.dir / f"shard_{int(merged['jobs'].min()):08d}.npz", merged)
            for p in paths:
                p.unlink(missing_ok=True)
