"""Why a 3D guide learns what it learns (issue #26): how strong the teacher of its traces is,
and which sites carry the traces' negative log-likelihood.

Teacher: for each setting N:SIGMA[:ESS] (unguided SMC with N particles under the voxel
likelihood with that sigma, resampling every step or when ESS < ESS * N), the mean over the
targets of the best tree's similarity (the usual scale, sigma-free) and CPU seconds per run,
one run per target (seed = the target's index), beside forward samples (N = 1) and the
guide at N = 10 under its own settings. The default targets are validation sets, never the
held-out `revolved`: blobs3d and extruded, 8 each, seed 1 (built in work/teacher3d when
missing).

Sites (`--traces DIR[,DIR]`): per site, the NLL per trace of the recorded values under the
prior and under the guide (temperatures 1), the teacher's choice frequencies per derivation
depth for categorical sites, so a site whose recorded values follow the prior (nothing to
learn) shows as one; then the target and partial windows' values per level (the window's
cells are listed x slowest, so the turtle's own cell is the middle one).

Usage: python benchmarks/teacher3d.py [--settings 1:0.02,10:0.02,100:0.02,100:0.05,...]
       [--targets DIR,DIR] [--guide G.onnx] [--traces DIR,DIR]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = "1:0.02,10:0.02,100:0.02,100:0.05,100:0.1,100:0.02:0.5,300:0.02,300:0.05"


def load_targets(dirs: str, program: Any) -> list[Any]:
    """The targets of the comma-separated set folders (the default sets built first)."""
    from ngpm_runtime.volume.load import load_volume_dataset

    from ngpm_compiler.cli import main

    out: list[Any] = []
    for d in dirs.split(","):
        path = Path(d)
        if not (path / "index.json").is_file():
            name = path.name.removeprefix("val_")
            main(["targets", "build", name, "-o", str(path), "--count", "8", "--seed", "1"])
        out += load_volume_dataset(path, program)
    return out


def teacher(program: Any, guide: Any, targets: list[Any], settings: list[str]) -> None:
    """Print mean best similarity and CPU s per run for each setting and the guide."""
    from ngpm_runtime.inference.smc import SMCOptions, smc
    from ngpm_runtime.volume.raster import VoxelGrid, voxelize
    from ngpm_runtime.volume.run import start_pose, volume_likelihood

    print(f"{len(targets)} targets; N:sigma[:ess] -> mean similarity, CPU s per run")
    for text in [*settings, "guide"]:
        parts = text.split(":")
        guided = text == "guide"
        n = 10 if guided else int(parts[0])
        sigma = None if guided else float(parts[1])
        ess = float(parts[2]) if len(parts) > 2 else None
        sims, cpu = [], 0.0
        for ti, t in enumerate(targets):
            like = volume_likelihood(program, t, sigma)
            opt = SMCOptions(
                seed=ti,
                start=start_pose(program, t),
                volume=t,
                ess_threshold=ess,
                ess_from_proposal=guided,
            )
            t0 = time.process_time()
            res = smc(program, like, n, guide if guided else None, opt)
            cpu += time.process_time() - t0
            vox = voxelize(list(res.best.primitives), VoxelGrid.of_target(t))
            sims.append(volume_likelihood(program, t).similarity(vox))
        label = f"guided N=10 ({guide.settings.label()})" if guided else text
        print(f"{label:28s} {np.mean(sims):7.3f}  {cpu / len(targets):6.2f} s", flush=True)


def sites(program: Any, guide: Any, traces: str) -> None:
    """Print per-site NLL per trace under the prior and the guide (temperatures 1)."""
    from ngpm_runtime.inference import distributions as dist
    from ngpm_runtime.inference.guide import ProposalSettings

    from ngpm_compiler.learning.trace_data import load_traces

    guide.settings = ProposalSettings()
    for d in traces.split(","):
        ts = load_traces(d)
        n = len(ts.kept_jobs)
        print(f"\n{d}: {n} traces; NLL per trace, prior -> guide")
        total = np.zeros(2)
        for site in ts.sites:
            data = ts.data.get(site.index)
            if data is None:
                continue
            lp = -dist.prior_logpdf(site, data.prior_args, data.values).sum() / n
            params = guide.params(site.index, data.features)
            lq = -dist.proposal_logpdf(site, data.prior_args, params, data.values).sum() / n
            total += (lp, lq)
            print(
                f"  {site.index:3d} {site.name[:32]:32s} {len(data.values):7d} visits "
                f"{lp:9.1f} -> {lq:9.1f}"
            )
            if site.kind == "categorical":
                choice_table(data, ts.layouts[site.index]["local"].start + 13, program)
        print(f"  all sites {total[0]:.1f} -> {total[1]:.1f}")
        windows(ts)


def windows(ts: Any) -> None:
    """Stats of the target and partial windows at each level over the busiest site's rows:
    mean of the cells inside the grid, std of the turtle's own cell, and the range over
    traces of the per-trace mean of that cell (does the target window vary?)."""
    site = max(ts.data, key=lambda i: len(ts.data[i].values))
    data, lay = ts.data[site], ts.layouts[site]
    for group in ("target", "partial"):
        block = data.features[:, lay[group]]
        k = block.shape[1] // 4
        for lv in range(4):
            cells = block[:, lv * k : (lv + 1) * k]
            own = cells[:, k // 2]
            per = [own[data.jobs == j].mean() for j in np.unique(data.jobs)]
            print(
                f"  {group} level {lv}: mean {cells[cells >= 0].mean():.2f}, turtle's cell "
                f"std {own.std():.2f}, per-trace mean {min(per):.2f} .. {max(per):.2f}"
            )


def choice_table(data: Any, depth_col: int, program: Any) -> None:
    """The recorded choices' frequencies per derivation depth, beside the prior's."""
    v = data.values.astype(int)
    k = data.prior_args.shape[1]
    depth = np.rint(data.features[:, depth_col] * program.derivation_length).astype(int)
    prior = np.round(data.prior_args[0] / data.prior_args[0].sum(), 2)
    print(f"      prior {prior}")
    for dp in np.unique(depth):
        m = depth == dp
        freq = np.round(np.bincount(v[m], minlength=k) / m.sum(), 2)
        print(f"      depth {dp}: {m.sum():6d} visits, recorded {freq}")


def main() -> None:
    from ngpm_runtime import bundled
    from ngpm_runtime.inference.guide import Guide

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    work = ROOT / "work" / "teacher3d"
    ap.add_argument("--targets", default=f"{work / 'val_blobs3d'},{work / 'val_extruded'}")
    ap.add_argument("--settings", default=SETTINGS, help="N:SIGMA[:ESS],... ('' for none)")
    ap.add_argument("--guide", help="guide .onnx (default: the bundled 3D guide)")
    ap.add_argument("--traces", help="trace folders: per-site NLL, prior vs guide")
    args = ap.parse_args()
    program = bundled.bundled_program3d()
    guide = Guide.load(args.guide, program) if args.guide else bundled.bundled_guide3d(program)
    if args.settings:
        settings = args.settings.split(",")
        teacher(program, guide, load_targets(args.targets, program), settings)
    if args.traces:
        sites(program, guide, args.traces)


if __name__ == "__main__":
    main()
