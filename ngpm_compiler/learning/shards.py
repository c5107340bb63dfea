"""Checks of a traces directory's files before any use: a shard or pending job (npz) and
manifest.json are checked field by field (names, dtypes, shapes, lengths, finite values), so a
damaged or edited file stops a command with one line that names the file and the field,
rather than a traceback or training data that is silently wrong.

A shard's arrays (`traces.job_arrays` writes them; a pending job is a shard of one job): per
job `jobs` int64 (distinct ids >= 0), `kept` bool, `n_prims` int64 (-1: SMC failed), `target`
int64, `seed` uint64, all of one length; per visited site `i`: `f_<i>` (m, n_f) float32
features (n_f: the site's layout width), `v_<i>` (m,) float64 values, `j_<i>` (m,) int64 ids
of kept jobs of the same file; features and values finite.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
from ngpm_runtime.errors import NgpmError
from ngpm_runtime.image.features import FEATURE_GROUPS
from ngpm_runtime.program import SITE_KINDS

JOB_ARRAYS = {
    "jobs": np.int64,
    "kept": np.bool_,
    "n_prims": np.int64,
    "target": np.int64,
    "seed": np.uint64,
}
SITE_ARRAYS = {"f": (np.float32, 2), "v": (np.float64, 1), "j": (np.int64, 1)}
SITE_KEY = re.compile(r"([fvj])_(0|[1-9][0-9]{0,8})")

# manifest.json: required fields, then optional ones, with their JSON types
MANIFEST_FIELDS = {"format": str, "key": dict, "grammar_hash": str, "sites": list, "layouts": dict}
MANIFEST_OPTIONAL = {
    "config": dict,
    "requested": int,
    "kept": int,
    "dropped": int,
    "failed": int,
    "jobs_done": int,
    "seconds": float,
    "job_seconds": list,
    "shards": list,
}
# the column groups every traces manifest has (those recorded since the far group existed
# also have "far")
LAYOUT_GROUPS = FEATURE_GROUPS["all+context"]


class TraceError(NgpmError):
    """A traces directory cannot be used (other configuration, corrupt shard)."""


class ShardError(TraceError):
    """A shard or pending job file is unreadable or malformed; `reason` names the field."""

    def __init__(self, path: str | Path, reason: str) -> None:
        super().__init__(f"{path}: corrupt trace shard: {reason}")
        self.path, self.reason = Path(path), reason


def read_npz(path: Path) -> dict[str, np.ndarray]:
    """Every array of an npz file (no pickled objects); ShardError if it is not one."""
    try:
        z = np.load(path, allow_pickle=False)
    except Exception as err:
        raise ShardError(path, f"not a readable npz file ({type(err).__name__})") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise ShardError(path, "not an npz file (a single array)")
    with z:
        out = {}
        for key in z.files:
            try:
                out[key] = z[key]
            except Exception as err:
                raise ShardError(
                    path, f"array {key!r} cannot be read ({type(err).__name__})"
                ) from None
    return out


def check_shard(path: Path, a: dict[str, np.ndarray], widths: dict[int, int] | None = None) -> None:
    """ShardError unless `a` is a well-formed shard (the module's docstring); with `widths`
    (site index -> feature columns), its sites and feature widths must be those."""
    _check_jobs(path, a)
    kept = set(a["jobs"][a["kept"]].tolist())
    sites = set()
    for key in a:
        if key not in JOB_ARRAYS:
            m = SITE_KEY.fullmatch(key)
            if m is None:
                raise ShardError(path, f"unexpected array {key!r}")
            sites.add(int(m.group(2)))
    for site in sorted(sites):
        _check_site(path, a, site, kept, widths)


def _check_array(path: Path, key: str, x: np.ndarray, dtype: Any, ndim: int) -> None:
    if x.dtype != np.dtype(dtype):
        raise ShardError(path, f"{key!r} has dtype {x.dtype}, not {np.dtype(dtype)}")
    if x.ndim != ndim:
        raise ShardError(path, f"{key!r} has shape {x.shape}, not {ndim}-dimensional")
    if x.dtype.kind == "f" and not np.isfinite(x).all():
        raise ShardError(path, f"{key!r} holds NaN or infinite values")


def _check_jobs(path: Path, a: dict[str, np.ndarray]) -> None:
    for key, dtype in JOB_ARRAYS.items():
        if key not in a:
            raise ShardError(path, f"no array {key!r}")
        _check_array(path, key, a[key], dtype, 1)
    lengths = {key: len(a[key]) for key in JOB_ARRAYS}
    if len(set(lengths.values())) != 1:
        raise ShardError(
            path,
            "the per-job arrays differ in length ("
            + ", ".join(f"{k} {n}" for k, n in lengths.items())
            + ")",
        )
    jobs = a["jobs"]
    if len(jobs) == 0:
        raise ShardError(path, "'jobs' is empty")
    if (jobs < 0).any() or len(np.unique(jobs)) != len(jobs):
        raise ShardError(path, "'jobs' holds a negative or repeated job id")
    if (a["n_prims"] < -1).any() or (a["target"] < 0).any():
        raise ShardError(path, "'n_prims' or 'target' holds a negative value")


def _check_site(
    path: Path, a: dict[str, np.ndarray], site: int, kept: set[int], widths: dict[int, int] | None
) -> None:
    for prefix, (dtype, ndim) in SITE_ARRAYS.items():
        key = f"{prefix}_{site}"
        if key not in a:
            raise ShardError(path, f"no array {key!r} for the other arrays of site {site}")
        _check_array(path, key, a[key], dtype, ndim)
    f, v, j = (a[f"{p}_{site}"] for p in SITE_ARRAYS)
    if not len(f) == len(v) == len(j):
        raise ShardError(
            path,
            f"the arrays of site {site} differ in length (f_{site} "
            f"{len(f)}, v_{site} {len(v)}, j_{site} {len(j)})",
        )
    if widths is not None and site not in widths:
        raise ShardError(path, f"'f_{site}': the grammar has no site {site}")
    if widths is not None and f.shape[1] != widths[site]:
        raise ShardError(
            path, f"'f_{site}' has {f.shape[1]} feature columns; site {site} has {widths[site]}"
        )
    stray = set(np.unique(j).tolist()) - kept
    if stray:
        raise ShardError(path, f"'j_{site}' names job {min(stray)}, not a kept job of this file")


# --------------------------------------------------------------------------- manifest


def check_manifest(path: Path, m: Any) -> None:
    """TraceError naming the field unless `m` (a parsed manifest.json) has every field that
    readers use, of the right type: configuration key, site table, feature layouts, counts."""
    if not isinstance(m, dict):
        raise TraceError(f"{path}: corrupt manifest: not a JSON object")
    for name in MANIFEST_FIELDS:
        if name not in m:
            raise TraceError(f"{path}: corrupt manifest: no field {name!r}")
    for name, kind in (MANIFEST_FIELDS | MANIFEST_OPTIONAL).items():
        if name in m and not _is(m[name], kind):
            raise TraceError(f"{path}: corrupt manifest: {name!r} is not {_KIND_WORDS[kind]}")
    if not isinstance(m["key"].get("grammar"), str):
        raise TraceError(f"{path}: corrupt manifest: 'key' has no grammar name")
    bad = [x for x in m.get("job_seconds", []) if not _is(x, float)]
    bad += [x for x in m.get("shards", []) if not isinstance(x, str)]
    if bad:
        raise TraceError(f"{path}: corrupt manifest: 'job_seconds' or 'shards' holds {bad[0]!r}")
    _check_sites(path, m["sites"], m["layouts"])


_KIND_WORDS = {
    str: "a string",
    dict: "an object",
    list: "a list",
    int: "a whole number >= 0",
    float: "a finite number >= 0",
}


def _is(value: Any, kind: type) -> bool:
    """JSON type check; numbers are not booleans, and are finite and >= 0."""
    if kind in (int, float):
        number = isinstance(value, int) or (kind is float and isinstance(value, float))
        return number and not isinstance(value, bool) and math.isfinite(value) and value >= 0
    return isinstance(value, kind)


def _check_sites(path: Path, sites: list[Any], layouts: dict[str, Any]) -> None:
    """Every site entry has an index, id and kind, and one layout of [start, stop] column
    ranges with every group of LAYOUT_GROUPS; no layout belongs to no site."""
    indices = []
    for n, s in enumerate(sites):
        if not (
            isinstance(s, dict)
            and _is(s.get("index"), int)
            and isinstance(s.get("id"), str)
            and s.get("kind") in SITE_KINDS
        ):
            raise TraceError(
                f"{path}: corrupt manifest: 'sites' entry {n} needs an index, "
                f"an id and a kind ({', '.join(SITE_KINDS)})"
            )
        indices.append(str(s["index"]))
    if sorted(indices) != sorted(layouts):
        raise TraceError(
            f"{path}: corrupt manifest: 'layouts' has sites "
            f"{sorted(layouts)}, 'sites' has {sorted(indices)}"
        )
    for i, lay in layouts.items():
        ok = (
            isinstance(lay, dict)
            and all(g in lay for g in LAYOUT_GROUPS)
            and all(
                isinstance(r, list) and len(r) == 2 and all(_is(x, int) for x in r) and r[0] <= r[1]
                for r in lay.values()
            )
        )
        if not ok:
            raise TraceError(
                f"{path}: corrupt manifest: 'layouts' entry {i!r} is not a set "
                f"of [start, stop] column ranges of the groups "
                f"{', '.join(LAYOUT_GROUPS)}"
            )


def layout_widths(layouts: dict[int, dict[str, slice]]) -> dict[int, int]:
    """Feature columns per site: the end of its last group."""
    return {i: max(sl.stop for sl in lay.values()) for i, lay in layouts.items()}
