"""One trace job: its target and SMC seed (`job_spec`, a pure function of the base seed and
the job id), the SMC run that keeps the best particle's trace (`run_job`) and the npz arrays
it is stored as (`job_arrays`). Shard / pending npz arrays: `jobs, kept, n_prims, target,
seed` (one entry per job; n_prims is -1 when SMC failed: every particle died, so the job is
dropped) and per visited site `i`: `f_<i>` (m, n_f) float32 features, `v_<i>` (m,) values,
`j_<i>` (m,) job ids."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from ngpm_runtime.program import Program

from ngpm_compiler.learning.shards import TraceError

if TYPE_CHECKING:
    from ngpm_runtime.image.raster import Viewport
    from ngpm_runtime.image.targets import Target
    from ngpm_runtime.inference.proposals import Proposal

MIN_PRIMITIVES = 10  # the paper's code dropped shorter traces

Trace = list[tuple[int, np.ndarray, float]]  # (site, features, value) per site visit


def viewport(program: Program, where: str | None = None) -> Viewport:
    """The grammar's viewport; TraceError without one (traces draw into target images).
    `where` names the grammar in the error (its file), else its name."""
    if program.viewport is None:
        raise TraceError(
            f"{where or 'grammar ' + program.name}: the grammar has no "
            "'viewport:' line; traces draw into target images, so add one "
            "(e.g. 'viewport: -12 12 -22 2'; `ngpmc check` proposes one)"
        )
    return program.viewport


def load_targets(directory: str | Path, size: int, mirror: bool) -> list[Target]:
    """The dataset's targets, plus mirrored copies of those without one when `mirror`."""
    from ngpm_runtime.image.targets import load_dataset

    targets = list(load_dataset(directory, size=size))
    if mirror:
        names = {t.name for t in targets}
        extra = [
            t.mirrored()
            for t in targets
            if not t.name.endswith("_m") and t.name + "_m" not in names
        ]
        targets.extend(extra)
    return targets


def job_spec(base_seed: int, job: int, n_targets: int) -> tuple[int, int]:
    """(target index, SMC seed) of job `job`: a pure function of its arguments."""
    a, b = np.random.SeedSequence([int(base_seed), int(job)]).generate_state(2)
    return int(a) % n_targets, int(b)


def run_job(
    program: Program,
    target: Target,
    seed: int,
    particles: int,
    guide: Proposal | None = None,
    max_modules: int | None = None,
) -> tuple[Trace, int]:
    """SMC (guided by `guide`, else unguided) on one target; the best particle's trace and
    primitive count.

    The run records values only; the best particle alone is then replayed with its values
    to compute its features (the same rows a run with features for every particle gives)."""
    from ngpm_runtime.errors import ProgramError
    from ngpm_runtime.grow import grow
    from ngpm_runtime.inference.smc import TraceRecording, replay

    start = target.start_pose(viewport(program))
    best = grow(
        program,
        target,
        guide,
        particles,
        seed,
        trace=TraceRecording.VALUES,
        max_modules=max_modules,
    ).smc.best
    values = [(s, v) for s, _, v in best.trace or []]
    again = replay(
        program,
        values,
        start=start,
        canvas_size=target.size,
        target_mask=target.mask,
        max_modules=max_modules,
    )
    if again.primitives != best.primitives:
        raise ProgramError(
            f"program {program.name}: replaying the best particle's values "
            "drew other primitives (generated code is not pure)"
        )
    trace: Trace = []
    for site, feats, value in again.trace or []:
        assert feats is not None  # a replay records every visit's features
        trace.append((site, feats, value))
    return trace, len(best.primitives)


def site_layouts(program: Program, target_mask: np.ndarray | None) -> dict[int, dict[str, slice]]:
    """FeatureMaker.layout for every site (traces record the context group too)."""
    from ngpm_runtime.image.features import FeatureMaker

    fm = FeatureMaker(program, viewport(program), target_mask, context=True)
    return {s.index: fm.layout(s) for s in program.sites}


def job_arrays(
    job: int, target: int, seed: int, trace: Trace, n_prims: int, kept: bool
) -> dict[str, np.ndarray]:
    """The npz arrays of one finished job (a dropped job records no site visits)."""
    out = {
        "jobs": np.array([job], np.int64),
        "kept": np.array([kept]),
        "n_prims": np.array([n_prims], np.int64),
        "target": np.array([target], np.int64),
        "seed": np.array([seed], np.uint64),
    }
    if kept:
        by_site: dict[int, list[tuple[np.ndarray, float]]] = {}
        for site, feats, value in trace:
            by_site.setdefault(int(site), []).append((feats, value))
        for site, rows in by_site.items():
            out[f"f_{site}"] = np.stack([np.asarray(f, np.float32) for f, _ in rows])
            out[f"v_{site}"] = np.array([v for _, v in rows], np.float64)
            out[f"j_{site}"] = np.full(len(rows), job, np.int64)
    return out
