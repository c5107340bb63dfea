"""SMC speed into 3D targets (issue #26), one core.

Default: unguided SMC (grow() with the voxel likelihood) of a 3D grammar, default
stochastic_tree3d.lsys (9 random sites; tree3d.lsys has none, so its SMC has one derivation
to find), at N = 10, 100 and 600 on procedural targets of R^3 voxels (default 32^3) laid over
the grammar's box: a crown on a trunk, a cone, and the envelope of one prior tree (the
voxels within 2 of a forward sample's, seed 99: a shape the grammar can fill). Runs are
interleaved (per seed, per target, every N in turn); printed per N: median ms per SMC step
(CPU and wall), median seconds per run (CPU and wall), median steps and the similarity of
the best particle per target (mean over seeds). "features N=10" is the first N with the 3D
feature rows computed for every site visit and given to a proposal that draws from the
prior (`PriorWithFeatures`): what the features add to a guided run, without its networks.

--features: the 3D feature rows' cost per row batch (FeatureMaker3D, one kernel call and
the site columns) for the 3x3x3 window ("cube", 216 window columns) and the 7-cell one
("cross", 56), at 10, 100 and 600 rows, on a canvas with a grown tree drawn in it.

Usage: python benchmarks/smc3d.py [--grammar stochastic_tree3d] [--resolution 32]
       [--seeds 1] [--ns 10,100,600] [--features]
Needs the compiler (ngpm_compiler) to compile the grammar. CPU seconds are reported as well
as wall seconds, with the load average: the machine may be shared.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path
from typing import Any

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def program_of(name: str) -> Any:
    from ngpm_compiler.language.compile import compile_grammar

    path = ROOT / "grammars" / f"{name}.lsys"
    return compile_grammar(path.read_text(), filename=str(path)).program()


def targets(program: Any, resolution: int) -> list[Any]:
    """Procedural VolumeTargets on a cube of resolution^3 voxels over the program's box."""
    from ngpm_runtime.inference.smc import forward
    from ngpm_runtime.volume.raster import VoxelGrid, voxelize
    from ngpm_runtime.volume.target import VolumeTarget

    grid = VoxelGrid.of_box(program.box, resolution)
    x, y, z = np.meshgrid(*(grid.centres(a) for a in range(3)), indexing="ij")
    b = program.box
    h = b[3] - b[2]
    w = min(b[1] - b[0], b[5] - b[4])
    trunk = (np.abs(x) < 0.05 * w) & (np.abs(z) < 0.05 * w) & (y > b[2]) & (y < b[2] + 0.5 * h)
    crown = x**2 + (y - b[2] - 0.6 * h) ** 2 + z**2 < (0.3 * h) ** 2
    rise = np.clip((y - b[2]) / h, 0, 1)
    cone = (np.hypot(x, z) < 0.4 * w * (1 - rise)) & (y > b[2])
    envelope = dilate(voxelize(forward(program, seed=99).primitives, grid).astype(bool), 2)
    start = np.array([program.start[0], program.start[1], 0.0])
    lo = np.array(grid.lo)
    return [
        VolumeTarget(occ, lo, grid.voxel, start, name)
        for name, occ in (("crown", trunk | crown), ("cone", cone), ("envelope", envelope))
    ]


def dilate(occ: np.ndarray, steps: int) -> np.ndarray:
    """occ grown by `steps` voxels (6-neighbourhood per step, not across the grid's edge)."""
    out = occ.copy()
    for _ in range(steps):
        grown = out.copy()
        grown[1:] |= out[:-1]
        grown[:-1] |= out[1:]
        grown[:, 1:] |= out[:, :-1]
        grown[:, :-1] |= out[:, 1:]
        grown[:, :, 1:] |= out[:, :, :-1]
        grown[:, :, :-1] |= out[:, :, 1:]
        out = grown
    return out


class PriorWithFeatures:
    """The prior as a proposal that asks for the 3D feature rows (as a guide does) and
    ignores them: what the features add to a step, without a guide's networks."""

    uses_features = True

    def propose(self, site: Any, args: np.ndarray, feats: Any, rng: Any) -> Any:
        from ngpm_runtime.inference.distributions import prior_draw

        return prior_draw(site, args, rng)


def step_table(program: Any, ts: list[Any], ns: list[int], seeds: int) -> None:
    """grow() at each N (unguided), and at the first N with the features computed,
    interleaved; one line per configuration."""
    from ngpm_runtime.grow import grow

    configs = [(f"unguided N={n}", n, None) for n in ns]
    configs.insert(1, (f"features N={ns[0]}", ns[0], PriorWithFeatures()))
    runs: dict[str, list[tuple[float, float, int, float]]] = {c[0]: [] for c in configs}
    sims: dict[tuple[str, str], list[float]] = {}
    grow(program, ts[0], PriorWithFeatures(), 2, seed=0)  # compile the kernels first
    for seed in range(seeds):
        for t in ts:
            for label, n, proposal in configs:
                c0, w0 = time.process_time(), time.perf_counter()
                res = grow(program, t, proposal, n, seed=seed)
                cpu, wall = time.process_time() - c0, time.perf_counter() - w0
                runs[label].append((cpu, wall, res.smc.steps, res.similarity))
                sims.setdefault((label, t.name), []).append(res.similarity)
    print(
        f"{'config':<16}{'ms/step cpu':>12}{'ms/step wall':>13}{'s/run cpu':>10}"
        f"{'s/run wall':>11}{'steps':>7}" + "".join(f"{'sim ' + t.name:>14}" for t in ts)
    )
    for label, _, _ in configs:
        r = runs[label]
        per_cpu = statistics.median(c / max(s, 1) * 1e3 for c, _, s, _ in r)
        per_wall = statistics.median(w / max(s, 1) * 1e3 for _, w, s, _ in r)
        print(
            f"{label:<16}{per_cpu:>12.2f}{per_wall:>13.2f}"
            f"{statistics.median(c for c, *_ in r):>10.2f}"
            f"{statistics.median(w for _, w, *_ in r):>11.2f}"
            f"{statistics.median(s for *_, s, _ in r):>7.0f}"
            + "".join(f"{statistics.fmean(sims[label, t.name]):>14.3f}" for t in ts)
        )


def feature_table(program: Any, target: Any, repeats: int = 200) -> None:
    """Microseconds per row batch of FeatureMaker3D.features, cube against cross."""
    from ngpm_runtime.grow import grow
    from ngpm_runtime.volume.features import FeatureMaker3D
    from ngpm_runtime.volume.raster import VoxelCanvas, VoxelGrid

    grid = VoxelGrid.of_target(target)
    prims = grow(program, target, None, 10, seed=0).primitives
    site = program.sites[0]
    rng = np.random.default_rng(0)
    print(
        f"{'rows':>6}{'cube us/batch':>15}{'cross us/batch':>16}{'cube cols':>11}{'cross cols':>12}"
    )
    for n in (10, 100, 600):
        canvas = VoxelCanvas(n, grid)
        for s in range(0, len(prims), 64):
            part = prims[s : s + 64]
            canvas.draw(np.zeros(len(part), dtype=np.intp), part)
        canvas.take(np.zeros(n, dtype=np.intp))
        segs = [p for p in prims if p[0] == "seg3"]
        turtles = []
        for _ in range(n):
            p = segs[int(rng.integers(len(segs)))]
            turtles.append((p[4], p[5], p[6], 0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0, p[7]))
        idx, depth = np.arange(n), np.zeros(n)
        args = np.zeros((n, site.n_args()))
        params = np.zeros((n, site.arity))
        cells = []
        for window in ("cube", "cross"):
            fm = FeatureMaker3D(program, grid, target, window=window)
            fm.features(site, canvas, idx, turtles, depth, params, args)
            t0 = time.perf_counter()
            for _ in range(repeats):
                rows = fm.features(site, canvas, idx, turtles, depth, params, args)
            cells.append(((time.perf_counter() - t0) / repeats * 1e6, rows.shape[1]))
        print(f"{n:>6}{cells[0][0]:>15.1f}{cells[1][0]:>16.1f}{cells[0][1]:>11}{cells[1][1]:>12}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--grammar", default="stochastic_tree3d")
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--ns", default="10,100,600")
    ap.add_argument("--features", action="store_true")
    args = ap.parse_args()
    program = program_of(args.grammar)
    ts = targets(program, args.resolution)
    load0 = os.getloadavg()[0]
    print(
        f"{args.grammar}, {len(program.sites)} sites, {args.resolution}^3 voxels, targets "
        f"{', '.join(t.name for t in ts)}, seeds {args.seeds}"
    )
    if args.features:
        feature_table(program, ts[0])
    else:
        step_table(program, ts, [int(x) for x in args.ns.split(",")], args.seeds)
    print(f"load average {load0:.1f} -> {os.getloadavg()[0]:.1f} (1 min)")


if __name__ == "__main__":
    main()
