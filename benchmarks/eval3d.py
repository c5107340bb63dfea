"""3D evaluation (issue #26): guided N = 10 against unguided N = 10 .. on held-out 3D
targets (the `revolved` set: round shapes, never trained on), one core, interleaved.

For every target and repeat the runs (guided N = 10, then unguided at each N) go in a
shuffled order, so a load change on the shared machine touches every model alike. Each run
is `grow()` of the 3D grammar (default: the bundled vines3d and its guide) into the
target at its resolution; its CPU seconds (time.process_time) and the best tree's
similarity are kept. Printed and written to OUT/eval3d.md (rows in OUT/eval3d_runs.csv):
the mean over targets of the per-target median similarity and the mean CPU seconds per
run for each model and N; the unguided N that matches the guide (log-interpolated,
runs.n_to_match); CPU time to reach the guide's similarity, unguided against guided
(runs.time_to_reach); and OUT/pictures/<target>.png: target | guided N = 10 | unguided
at the largest N (seed 0), drawn at one scale.

Usage: python benchmarks/eval3d.py [--targets DIR] [--guide G.onnx] [--grammar G.lsys]
       [--k 24] [--repeats 2] [--ns 10,30,100,300,600] [--pictures 3] [--out DIR]
--targets defaults to work/revolved, built there first when missing (ngpmc targets build
revolved). Needs the compiler (ngpm_compiler) to build targets and compile a grammar.
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
GUIDED, UNGUIDED = "guided", "unguided"
FIELDS = ["model", "dataset", "target", "n", "repeat", "seed", "similarity", "seconds"]


def load(args: argparse.Namespace) -> tuple[Any, Any, list[Any]]:
    """(program, guide, targets) from the options."""
    from ngpm_runtime import bundled
    from ngpm_runtime.inference.guide import Guide
    from ngpm_runtime.volume.load import load_volume_dataset

    from ngpm_compiler.cli import main
    from ngpm_compiler.evaluation.runs import pick
    from ngpm_compiler.language.compile import load_grammar

    program = load_grammar(args.grammar) if args.grammar else bundled.bundled_program3d()
    if args.guide:
        guide = Guide.load(args.guide, program)
    else:
        guide = bundled.bundled_guide3d(program)
    targets_dir = Path(args.targets)
    if not (targets_dir / "index.json").is_file():
        main(["targets", "build", "revolved", "-o", str(targets_dir)])
    targets = pick(load_volume_dataset(targets_dir, program), args.k)
    return program, guide, targets


def measure(program: Any, guide: Any, targets: list[Any], ns: list[int], repeats: int) -> list:
    """Every run, interleaved (shuffled per target and repeat); rows of FIELDS."""
    from ngpm_runtime.grow import grow

    from ngpm_compiler.evaluation.runs import run_seed

    rows = []
    rng = np.random.default_rng(0)
    for ti, target in enumerate(targets):
        for rep in range(repeats):
            runs = [(GUIDED, 10)] + [(UNGUIDED, n) for n in ns]
            for k in rng.permutation(len(runs)):
                model, n = runs[k]
                seed = run_seed(3000, ti, n, rep)
                t0 = time.process_time()
                res = grow(program, target, guide if model == GUIDED else None, n, seed)
                cpu = time.process_time() - t0
                rows.append(
                    dict(
                        zip(
                            FIELDS,
                            [model, "revolved", target.name, n, rep, seed, res.similarity, cpu],
                            strict=True,
                        )
                    )
                )
            print(f"{target.name} repeat {rep}: done", flush=True)
    return rows


def report(rows: list[dict[str, Any]], ns: list[int], load_avg: str) -> str:
    """The markdown summary: similarity and CPU seconds per model and N, crossing N, time
    ratio at the guide's similarity."""
    import math

    from ngpm_compiler.evaluation.runs import curve, n_to_match, summarize, time_to_reach

    summary = summarize(rows, "revolved")
    lines = [
        f"held-out `revolved`, {len({r['target'] for r in rows})} targets, one core, "
        f"{load_avg} at the end",
        "",
        "| model | N | mean similarity (95% CI) | CPU s per run |",
        "|---|---|---|---|",
    ]
    for s in summary:
        lines.append(
            f"| {s['model']} | {s['n']} | {s['mean_similarity']:.3f} "
            f"({s['ci_low']:.3f} .. {s['ci_high']:.3f}) | {s['mean_seconds']:.3f} |"
        )
    g = [s for s in summary if s["model"] == GUIDED][0]
    match = n_to_match(summary, float(g["mean_similarity"]))
    _, us, ut = curve(summary, UNGUIDED)
    tu = time_to_reach(us, ut, float(g["mean_similarity"]))
    ratio = tu / float(g["mean_seconds"]) if not math.isnan(tu) else math.nan
    top = max(ns)
    lines += [
        "",
        f"guided N=10: similarity {g['mean_similarity']:.3f} in {g['mean_seconds']:.3f} CPU s",
        "unguided N to match it: " + (f">{top}" if math.isnan(match) else f"{match:.0f}"),
        "unguided CPU s to reach it: "
        + (
            f"more than {ut.max():.3f} (never reached)"
            if math.isnan(tu)
            else f"{tu:.3f} ({ratio:.1f}x the guided run's)"
        ),
        "",
        *paired(rows, ns),
    ]
    return "\n".join(lines) + "\n"


def paired(rows: list[dict[str, Any]], ns: list[int]) -> list[str]:
    """Guided N = 10 minus unguided at each N, target by target (the median of each's
    runs): the mean difference with half its 95% interval over targets, and on how many
    targets the guide scored higher (the same seeds and targets: a sharper test of "as good
    as unguided N" than two overlapping intervals)."""
    import statistics

    by: dict[tuple[str, int, str], list[float]] = {}
    for r in rows:
        by.setdefault((r["model"], int(r["n"]), r["target"]), []).append(float(r["similarity"]))
    targets = sorted({r["target"] for r in rows})
    guided = [statistics.median(by[(GUIDED, 10, t)]) for t in targets]
    lines = []
    for n in ns:
        d = [
            g - statistics.median(by[(UNGUIDED, n, t)])
            for g, t in zip(guided, targets, strict=True)
        ]
        half = 1.96 * statistics.stdev(d) / len(d) ** 0.5 if len(d) > 1 else float("nan")
        wins = sum(x > 0 for x in d)
        lines.append(
            f"guided N=10 - unguided N={n}, per target: {statistics.mean(d):+.3f} +- {half:.3f} "
            f"(guided higher on {wins} of {len(d)})"
        )
    return lines


def pictures(program: Any, guide: Any, targets: list[Any], n_big: int, out: Path) -> None:
    """out/pictures/<target>.png: target | guided N=10 | unguided N=n_big, seed 0."""
    from ngpm_runtime.geometry.mesh import mesh_from_primitives
    from ngpm_runtime.grow import grow
    from ngpm_runtime.image.render3d import render_side_by_side, save_png

    (out / "pictures").mkdir(parents=True, exist_ok=True)
    for t in targets:
        trees = [grow(program, t, g, n, 0).primitives for g, n in ((guide, 10), (None, n_big))]
        meshes = [t.mesh(), *(mesh_from_primitives(p) for p in trees)]
        save_png(render_side_by_side(meshes, 256), out / "pictures" / f"{t.name}.png")


def command_line(ap: argparse.ArgumentParser, args: argparse.Namespace) -> str:
    """The command as run, for the report's first line: the options that shape the table,
    and the paths given that are not the defaults (inside the checkout, relative to it)."""
    command = f"python benchmarks/eval3d.py --k {args.k} --repeats {args.repeats} --ns {args.ns}"
    for dest in ("targets", "grammar", "guide", "out"):
        value = getattr(args, dest)
        if value != ap.get_default(dest):
            path = Path(value).resolve()
            shown = str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else value
            command += f" --{dest} {shown}"
    return command


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--targets", default=str(ROOT / "work" / "revolved"))
    ap.add_argument("--grammar", help="3D grammar (default: the bundled vines3d)")
    ap.add_argument("--guide", help="guide .onnx (default: the bundled 3D guide)")
    ap.add_argument("--k", type=int, default=24, help="targets (spread over the set)")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--ns", default="10,30,100,300,600", help="unguided particle counts")
    ap.add_argument("--pictures", type=int, default=3, help="targets drawn (first k)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "3d"))
    return ap


def main() -> None:
    from ngpm_compiler.evaluation.runs import write_csv

    ap = parser()
    args = ap.parse_args()
    ns = sorted({int(x) for x in args.ns.split(",")})
    program, guide, targets = load(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = measure(program, guide, targets, ns, args.repeats)
    write_csv(out / "eval3d_runs.csv", rows, FIELDS)
    load_avg = f"load average {os.getloadavg()[0]:.1f}"
    text = report(rows, ns, load_avg)
    print(text)
    from ngpm_runtime.files import atomic_write

    atomic_write(out / "eval3d.md", f"`{command_line(ap, args)}`\n\n{text}".encode())
    pictures(program, guide, targets[: args.pictures], max(ns), out)


if __name__ == "__main__":
    main()
