"""Loading a traces directory as training data: the kept traces' site visits, per site."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from ngpm_runtime.program import Site

from ngpm_compiler.learning.shards import TraceError, layout_widths
from ngpm_compiler.learning.trace_store import TRACE_FORMAT, TraceStore

JOB_STRIDE = 10**8  # job ids of the k-th merged traces directory are offset by k * this


@dataclass
class SiteData:
    """Every recorded visit of one site: raw features, chosen values, prior args, job ids."""

    features: np.ndarray  # (m, n_f) float32
    values: np.ndarray  # (m,) float64
    prior_args: np.ndarray  # (m, n_args) float64
    jobs: np.ndarray  # (m,) int64: the trace each row belongs to


def prior_arg_columns(site: Site, layout: dict[str, slice]) -> slice:
    """Columns of the prior arguments: the last `n_args` of the local group (section 6)."""
    stop = layout["local"].stop
    return slice(stop - site.n_args(), stop)


@dataclass
class TraceSet:
    manifest: dict[str, Any]
    sites: list[Site]
    layouts: dict[int, dict[str, slice]]
    data: dict[int, SiteData]
    kept_jobs: np.ndarray
    dropped: int


def load_traces(directory: str | Path, allow_missing: bool = False) -> TraceSet:
    """The kept traces of a traces directory, as training data per site. TraceError when
    shards that the manifest lists are missing or unreadable, unless `allow_missing`."""
    store = TraceStore(directory)
    manifest = store.manifest()
    if manifest is None or manifest.get("format") != TRACE_FORMAT:
        raise TraceError(
            f"{store.dir}: not a traces directory (no manifest.json from `ngpmc traces`)"
        )
    sites = [Site.from_json(s) for s in manifest["sites"]]
    layouts = {
        int(i): {g: slice(a, b) for g, (a, b) in lay.items()}
        for i, lay in manifest["layouts"].items()
    }
    store.widths = layout_widths(layouts)
    unreadable: list[str] = []
    done = store.finished(unreadable)
    kept_jobs = np.sort(done["jobs"][done["kept"]])
    _check_complete(store, manifest, unreadable, len(kept_jobs), allow_missing)
    data: dict[int, SiteData] = {}
    for site in sites:
        f = done.get(f"f_{site.index}")
        if f is None or len(f) == 0:
            continue
        v, j = done[f"v_{site.index}"], done[f"j_{site.index}"]
        args = f[:, prior_arg_columns(site, layouts[site.index])].astype(np.float64)
        data[site.index] = SiteData(f, v, args, j)
    return TraceSet(
        manifest, sites, layouts, data, kept_jobs, int(len(done["jobs"]) - len(kept_jobs))
    )


def _check_complete(
    store: TraceStore,
    manifest: dict[str, Any],
    unreadable: list[str],
    kept: int,
    allow_missing: bool,
) -> None:
    """TraceError naming the shards the manifest lists that are gone or unreadable (and the
    kept traces that are missing), unless `allow_missing`; then only a warning on stderr."""
    present = {p.name for p in store.shard_paths()}
    gone = [name for name in manifest.get("shards", []) if name not in present]
    lost = max(0, int(manifest.get("kept", kept)) - kept)
    if not (gone or unreadable or lost):
        return
    problems = []
    if gone:
        problems.append(f"missing {', '.join(gone)}")
    if unreadable:
        problems.append(f"unreadable {', '.join(unreadable)}")
    text = (
        f"{store.dir}: {'; '.join(problems) or 'files missing'}: {kept} of the "
        f"{kept + lost} kept traces are there"
    )
    if allow_missing:
        print(f"ngpmc: warning: {text}; training on those (--allow-missing)", file=sys.stderr)
        return
    raise TraceError(
        f"{text}; restore the files, run `ngpmc traces` again with the same "
        "options to redo the lost jobs (after removing unreadable shards), or "
        "pass --allow-missing to train on what is there"
    )
