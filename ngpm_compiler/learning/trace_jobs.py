"""One trace job: its target and SMC seed (`job_spec`, a pure function of the base seed and
the job id), the SMC run that keeps the best particle's trace (`run_job`) and the npz arrays
it is stored as (`job_arrays`). Shard / pending npz arrays: `jobs, kept, n_prims, target,
seed` (one entry per job; n_prims is -1 when SMC failed: every particle died, so the job is
dropped) and per visited site `i`: `f_<i>` (m, n_f) float32 features, `v_<i>` (m,) values,
`j_<i>` (m,) job ids.

A 3D grammar (Program.dim == 3) records into a 3D target set (`ngpmc targets build`,
VolumeTarget): its rows are volume/features.py's (local, target, partial; no context)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from ngpm_runtime.program import Program

from ngpm_compiler.learning.shards import TraceError

if TYPE_CHECKING:
    from ngpm_runtime.image.raster import Viewport
    from ngpm_runtime.inference.proposals import Proposal

# A job is kept when its best particle drew at least this many primitives. Short traces are
# kept as data: such a particle is still the SMC's answer for its target, and dropping it
# throws its whole run away (benchmarks/short_traces.py, vines: 21% of unguided 600-particle
# jobs, a kept trace then costing 26% more). `--min-primitives` drops them on request.
MIN_PRIMITIVES = 1
PAPER_MIN_PRIMITIVES = 10  # the paper's code dropped shorter traces (its evaluation does)

Trace = list[tuple[int, np.ndarray, float]]  # (site, features, value) per site visit


def check_frame(program: Program, where: str | None = None) -> None:
    """TraceError unless the grammar has what its targets are placed in: a 2D viewport,
    or a 3D grammar's box (`viewport:` with six numbers)."""
    if program.dim != 3:
        viewport(program, where)
    elif program.box is None:
        raise TraceError(
            f"{where or 'grammar ' + program.name}: the 3D grammar has no "
            "'viewport: XMIN XMAX YMIN YMAX ZMIN ZMAX' line; traces grow into 3D "
            "targets placed in that box"
        )


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


def load_targets(
    directory: str | Path, size: int, mirror: bool, program: Program | None = None
) -> list[Any]:
    """The dataset's targets, plus mirrored copies of those without one when `mirror`.
    A 3D `program` loads a 3D target set (VolumeTargets placed in its box; `size` is not
    used: the set's own resolution)."""
    from ngpm_runtime.image.targets import load_dataset

    if program is not None and program.dim == 3:
        return load_volume_targets(directory, mirror, program)

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


def load_volume_targets(directory: str | Path, mirror: bool, program: Program) -> list[Any]:
    """The 3D target set in `directory` placed in the program's box (TraceError when it is
    not one, or with `mirror`: a 3D set is mirrored when built, `ngpmc targets build
    --mirror`)."""
    from ngpm_runtime.errors import TargetError
    from ngpm_runtime.volume.load import load_volume_dataset

    if mirror:
        raise TraceError(
            "--mirror is for pictures; build a 3D set with mirrored copies instead "
            "(ngpmc targets build NAME -o DIR --mirror)"
        )
    try:
        return list(load_volume_dataset(directory, program))
    except TargetError as err:
        raise TraceError(f"{err} (a 3D grammar records traces into a 3D target set)") from None


def start_of(program: Program, target: Any) -> tuple[float, ...]:
    """The world start pose of a run into `target` (a 2D Target or a VolumeTarget)."""
    if program.dim == 3:
        from ngpm_runtime.volume.run import start_pose

        return start_pose(program, target)
    return cast("tuple[float, ...]", target.start_pose(viewport(program)))


def job_spec(base_seed: int, job: int, n_targets: int) -> tuple[int, int]:
    """(target index, SMC seed) of job `job`: a pure function of its arguments."""
    a, b = np.random.SeedSequence([int(base_seed), int(job)]).generate_state(2)
    return int(a) % n_targets, int(b)


def run_job(
    program: Program,
    target: Any,
    seed: int,
    particles: int,
    guide: Proposal | None = None,
    max_modules: int | None = None,
    likelihood: str = "shape",
    sigma: float | None = None,
) -> tuple[Trace, int]:
    """SMC (guided by `guide`, else unguided) on one target under `likelihood`; the best
    particle's trace and primitive count. Under "circuit" the target gives the start and
    canvas size only, and the features see no target (as `grow` runs it). sigma: the 3D
    voxel likelihood's (None: the default).

    The run records values only; the best particle alone is then replayed with its values
    to compute its features (the same rows a run with features for every particle gives)."""
    from ngpm_runtime.grow import grow
    from ngpm_runtime.inference.smc import TraceRecording

    best = grow(
        program,
        target,
        guide,
        particles,
        seed,
        likelihood,
        trace=TraceRecording.VALUES,
        max_modules=max_modules,
        sigma=sigma,
    ).smc.best
    return replay_features(program, best, target, max_modules, likelihood), len(best.primitives)


def replay_features(
    program: Program,
    particle: Any,
    target: Any,
    max_modules: int | None = None,
    likelihood: str = "shape",
) -> Trace:
    """A particle's values replayed into `target` for their features (a 2D target's mask
    only under the shape likelihood; a 3D target as the volume): its trace with every
    visit's feature row. ProgramError when the replay draws other primitives."""
    from ngpm_runtime.errors import ProgramError
    from ngpm_runtime.inference.smc import replay

    values = [(s, v) for s, _, v in particle.trace or []]
    start = start_of(program, target)
    if program.dim == 3:
        again = replay(program, values, start=start, max_modules=max_modules, volume=target)
    else:
        again = replay(
            program,
            values,
            start=start,
            canvas_size=target.size,
            target_mask=target.mask if likelihood == "shape" else None,
            max_modules=max_modules,
        )
    if again.primitives != particle.primitives:
        raise ProgramError(
            f"program {program.name}: replaying a particle's values "
            "drew other primitives (generated code is not pure)"
        )
    trace: Trace = []
    for site, feats, value in again.trace or []:
        assert feats is not None  # a replay records every visit's features
        trace.append((site, feats, value))
    return trace


def own_sample(
    program: Program, seed: int, size: int, max_modules: int | None = None
) -> tuple[Any, Any] | None:
    """A forward sample of the grammar whose envelope (datasets/envelopes.py, size x size)
    covers at least MIN_INK of the canvas, and that envelope as a Target: (sample, target),
    the sample's trace holding its values; None when MAX_TRIES samples drew too little."""
    from ngpm_runtime.image.targets import Target
    from ngpm_runtime.inference.smc import SMCOptions, TraceRecording, smc

    from ngpm_compiler.datasets.envelopes import MAX_TRIES, MIN_INK, envelope
    from ngpm_compiler.datasets.envelopes import start_of as envelope_start

    seeds = np.random.SeedSequence(int(seed)).generate_state(MAX_TRIES, np.uint64) >> 1
    for s in seeds:
        options = SMCOptions(seed=int(s), trace=TraceRecording.VALUES, max_modules=max_modules)
        sample = smc(program, None, 1, options=options).particles[0]
        mask = envelope(list(sample.primitives), program, size)
        if mask.mean() >= MIN_INK:
            return sample, Target(mask, envelope_start(program), "own")
    return None


def run_own_job(
    program: Program, seed: int, size: int, max_modules: int | None = None
) -> tuple[Trace, int]:
    """One ground-truth trace (`TraceConfig.own_samples`): an `own_sample` and its values
    replayed into its envelope for their features; (trace, primitives), ([], 0) when no
    sample drew enough. For targets that are envelopes of the grammar's samples this is the
    posterior's own data: the sample that made the target is an exact draw of what SMC
    searches for there."""
    found = own_sample(program, seed, size, max_modules)
    if found is None:
        return [], 0
    sample, target = found
    return replay_features(program, sample, target, max_modules), len(sample.primitives)


def site_layouts(
    program: Program, target: Any = None, window: str | None = None
) -> dict[int, dict[str, slice]]:
    """FeatureMaker.layout for every site (2D traces record the context and far groups too); a 3D
    grammar's: FeatureMaker3D.layout on the target's grid with `window` (None: the
    default; its context group empty)."""
    from ngpm_runtime.image.features import FeatureMaker

    if program.dim == 3:
        from ngpm_runtime.volume.features import DEFAULT_WINDOW, FeatureMaker3D
        from ngpm_runtime.volume.raster import VoxelGrid

        fm3 = FeatureMaker3D(program, VoxelGrid.of_target(target), window=window or DEFAULT_WINDOW)
        out = {s.index: fm3.layout(s) for s in program.sites}
        for lay in out.values():  # every traces manifest has the group: empty in 3D
            lay["context"] = slice(lay["partial"].stop, lay["partial"].stop)
        return out
    target_mask = target.mask if target is not None else None

    fm = FeatureMaker(program, viewport(program), target_mask, context=True, far=True)
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
