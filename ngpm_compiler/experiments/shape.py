"""Shape matching study (paper Figs. 2, 4, 5, 6): test targets, guides, runs, plots, grids.

Files written to the results directory:
- shape_runs.csv      one row per SMC run (runs.RUN_FIELDS)
- shape_summary.csv   per dataset ("all", "glyphs", "silhouettes"), model and N
- speedup.csv         time to reach each similarity threshold, speedup over unguided
- trainset.csv        similarity at N = trainset_n vs number of training traces
- models.csv          the guides used (features, K, traces, validation NLL, training time)
- fig4a_similarity.png, fig4b_time.png, fig5a_mixture.png, fig5b_trainset.png
- grid_glyphs.png, grid_silhouettes.png, grids.csv (paper Figs. 2 and 6)
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from ngpm_runtime.geometry.turtle import Prim

from ngpm_compiler.evaluation.runs import (
    RUN_FIELDS,
    SUMMARY_FIELDS,
    UNGUIDED,
    RunTask,
    curve,
    grow_once,
    pick,
    read_csv,
    run_seed,
    run_tasks,
    shape_tasks,
    speedups,
    summarize,
    write_csv,
)
from ngpm_compiler.experiments import plots
from ngpm_compiler.experiments.config import SHAPE_MODELS, ShapeConfig
from ngpm_compiler.experiments.models import ModelSpec, model_info, train_models

TEST_SETS = ("glyphs", "silhouettes")


def test_targets(cfg: ShapeConfig) -> dict[str, list[Any]]:
    """The held-out test targets: evenly spread glyphs and silhouettes (built if needed)."""
    from ngpm_runtime.image.targets import load_dataset

    from ngpm_compiler.datasets.build import build_dataset

    out = {}
    for name, given, k in (
        ("glyphs", cfg.glyphs, cfg.n_glyphs),
        ("silhouettes", cfg.silhouettes, cfg.n_silhouettes),
    ):
        if k <= 0:
            continue
        d = Path(given) if given else Path(cfg.work) / name
        if not given and not (d / "index.json").is_file():
            build_dataset(name, d, count=k if cfg.quick else None, seed=cfg.seed)
        ts = [t for t in load_dataset(d, size=50) if not t.name.endswith("_m")]
        out[name] = pick(ts, k)
    return out


def tiny_traces(cfg: ShapeConfig) -> str:
    """A few unguided-SMC traces on a few scribbles (quick mode / no canonical traces)."""
    from ngpm_compiler.datasets.build import build_dataset
    from ngpm_compiler.learning.trace_jobs import PAPER_MIN_PRIMITIVES
    from ngpm_compiler.learning.traces import TraceConfig, generate_traces

    w = Path(cfg.work)
    scr = w / "scribbles"
    if not (scr / "index.json").is_file():
        build_dataset("scribbles", scr, count=cfg.tiny_scribbles, seed=cfg.seed, mirror=True)
    out = w / "traces"
    generate_traces(
        TraceConfig(
            grammar=cfg.grammar,
            targets=str(scr),
            n=cfg.tiny_traces,
            particles=cfg.tiny_particles,
            seed=cfg.seed,
            workers=1,
            min_primitives=PAPER_MIN_PRIMITIVES,  # the paper's evaluation
        ),
        out,
        progress=False,
    )
    return str(out)


def model_specs(cfg: ShapeConfig, kept: int) -> list[ModelSpec]:
    """The shape-matching guides: feature ablation, K = 1, training-set sizes."""
    specs = [ModelSpec(f, f, 4, None, cfg.epochs) for f in SHAPE_MODELS]
    if cfg.guide_all:
        specs = [s for s in specs if s.name != "all"]
    specs.append(ModelSpec("all_k1", "all", 1, None, cfg.epochs))
    for n in cfg.trainset_sizes:
        if n < kept:
            specs.append(ModelSpec(f"all_n{n}", "all", 4, n, cfg.epochs))
    return specs


def trainset_models(cfg: ShapeConfig, kept: int) -> dict[int, str]:
    """{training traces: model name} for the training-set-size curve."""
    out = {n: f"all_n{n}" for n in cfg.trainset_sizes if n < kept}
    out[kept] = "all"
    return out


def models_table(guides: dict[str, str], kept: int) -> list[dict[str, Any]]:
    rows = []
    for name, path in sorted(guides.items()):
        info = model_info(path)
        spec = info.get("key", {}).get("spec", {})
        rows.append(
            {
                "model": name,
                "features": spec.get("features", "all"),
                "K": spec.get("K", 4),
                "traces": info.get("traces", kept),
                "val_traces": info.get("val_traces", ""),
                "best_epoch": info.get("best_epoch", ""),
                "val_nll": _round(info.get("val_nll")),
                "train_seconds": _round(info.get("seconds")),
                "path": path,
            }
        )
    return rows


def _round(x: Any) -> Any:
    return "" if x is None else round(float(x), 3)


def run_shape(
    cfg: ShapeConfig,
    targets: dict[str, list[Any]],
    guides: dict[str, str],
    kept: int,
    log: Any = print,
) -> list[dict[str, Any]]:
    """Every SMC run of the shape study; writes shape_runs.csv and returns its rows."""
    counts = {ds: len(ts) for ds, ts in targets.items()}
    tasks = shape_tasks([UNGUIDED, "all"], counts, cfg.ns, cfg.repeats, cfg.seed)
    ablation = [m for m in SHAPE_MODELS if m != "all"]
    tasks += shape_tasks(
        ablation, counts, [n for n in cfg.ns if n <= cfg.ablation_max_n], cfg.repeats, cfg.seed
    )
    tasks += shape_tasks([UNGUIDED], counts, cfg.unguided_extra_ns, cfg.repeats, cfg.seed)
    tasks += shape_tasks(["all_k1"], counts, cfg.k1_ns, cfg.repeats, cfg.seed)
    ts_models = [m for m in trainset_models(cfg, kept).values() if m != "all"]
    tasks += shape_tasks(ts_models, counts, (cfg.trainset_n,), cfg.repeats, cfg.seed)
    tasks = list(dict.fromkeys(tasks))
    done = [0]

    def progress(_r: Any) -> None:
        done[0] += 1
        if done[0] % max(1, len(tasks) // 20) == 0 or done[0] == len(tasks):
            log(f"shape runs: {done[0]}/{len(tasks)}")

    where = (
        f"{cfg.workers} worker(s)"
        if cfg.backend == "local"
        else f"Ray ({cfg.ray_address or 'local instance'})"
    )
    log(f"shape runs: {len(tasks)} SMC runs, {where}")
    results = run_tasks(
        cfg.grammar,
        targets,
        guides,
        tasks,
        cfg.workers,
        cfg.seed,
        progress,
        backend=cfg.backend,
        address=cfg.ray_address,
    )
    rows = [r.row() for r in results]
    write_csv(Path(cfg.out) / "shape_runs.csv", rows, RUN_FIELDS)
    return rows


def analyze_shape(cfg: ShapeConfig, rows: list[dict[str, Any]], kept: int) -> dict[str, Any]:
    """Summaries, speedups, training-set curve and the four plots from the run rows."""
    out = Path(cfg.out)
    summary = summarize(rows, "all")
    for ds in TEST_SETS:
        sub = [r for r in rows if r["dataset"] == ds]
        if sub:
            summary += summarize(sub, ds)
    write_csv(out / "shape_summary.csv", summary, SUMMARY_FIELDS)
    overall = [r for r in summary if r["dataset"] == "all"]
    speed = speedups(overall, list(SHAPE_MODELS), cfg.thresholds)
    write_csv(
        out / "speedup.csv",
        speed,
        ("model", "threshold", "seconds", "baseline_seconds", "speedup", "bound"),
    )
    ts_rows = []
    for n, m in sorted(trainset_models(cfg, kept).items()):
        for r in overall:
            if r["model"] == m and int(r["n"]) == cfg.trainset_n:
                ts_rows.append(
                    {
                        "traces": n,
                        "model": m,
                        "n": cfg.trainset_n,
                        "mean_similarity": r["mean_similarity"],
                        "ci_low": r["ci_low"],
                        "ci_high": r["ci_high"],
                    }
                )
    write_csv(
        out / "trainset.csv",
        ts_rows,
        ("traces", "model", "n", "mean_similarity", "ci_low", "ci_high"),
    )
    main = [UNGUIDED, *SHAPE_MODELS]
    plots.plot_similarity_vs_n(
        overall,
        main,
        out / "fig4a_similarity.png",
        "Shape matching: similarity vs particles (held-out targets)",
    )
    plots.plot_time_vs_similarity(overall, speed, list(SHAPE_MODELS), out / "fig4b_time.png")
    plots.plot_similarity_vs_n(
        overall,
        [UNGUIDED, "all", "all_k1"],
        out / "fig5a_mixture.png",
        "Mixture components: K = 4 vs K = 1",
    )
    ung = next(
        (r for r in overall if r["model"] == UNGUIDED and int(r["n"]) == cfg.trainset_n), None
    )
    plots.plot_trainset_size(ts_rows, ung, out / "fig5b_trainset.png", cfg.trainset_n)
    return {"summary": summary, "speedup": speed, "trainset": ts_rows}


def prepare_guides(cfg: ShapeConfig, traces: str, kept: int, log: Any = print) -> dict[str, str]:
    specs = model_specs(cfg, kept)
    log(f"training {len(specs)} guides on {traces}: {', '.join(s.name for s in specs)}")
    guides = train_models(specs, traces, str(Path(cfg.work) / "models"), cfg.workers, cfg.seed)
    if cfg.guide_all:
        guides["all"] = cfg.guide_all
    write_csv(
        Path(cfg.out) / "models.csv",
        models_table(guides, kept),
        (
            "model",
            "features",
            "K",
            "traces",
            "val_traces",
            "best_epoch",
            "val_nll",
            "train_seconds",
            "path",
        ),
    )
    return guides


# --------------------------------------------------------------------------- grids


def equal_time_n(summary: list[dict[str, Any]], seconds: float, n_min: int) -> int:
    """The unguided N whose mean time matches `seconds` (log-log interpolation)."""
    ns, _, ts = curve(summary, UNGUIDED)
    if not len(ns):
        return n_min
    ok = ts > 0
    ns, ts = ns[ok], ts[ok]
    if not len(ns):
        return n_min
    order = np.argsort(ts)
    ns, ts = ns[order], ts[order]
    seconds = max(seconds, 1e-6)
    ln = float(np.interp(math.log(seconds), np.log(ts), np.log(ns.astype(float))))
    # outside the measured range: time roughly linear in N
    if seconds > ts[-1]:
        ln = math.log(ns[-1]) + math.log(seconds / ts[-1])
    elif seconds < ts[0]:
        ln = math.log(ns[0]) + math.log(seconds / ts[0])
    return max(n_min, int(round(math.exp(ln))))


def equal_time_run(
    program: Any,
    target: Any,
    seconds: float,
    n: int,
    n_min: int,
    seed: int,
    tries: int = 4,
    n_max: int = 5000,
) -> tuple[float, float, list[Prim], int]:
    """Unguided SMC whose wall time is closest to `seconds`: start from the estimate `n`,
    rescale N by the time ratio (at most x4 per try) until within 25%; returns
    (similarity, seconds, primitives, N) of the try closest in time."""
    tried = []
    for _ in range(tries):
        sim, secs, prims = grow_once(program, target, None, n, seed)
        tried.append((abs(math.log(max(secs, 1e-6) / max(seconds, 1e-6))), sim, secs, prims, n))
        ratio = min(4.0, max(0.25, seconds / max(secs, 1e-6)))
        if 0.8 <= ratio <= 1.25:
            break
        new_n = min(n_max, max(n_min, int(round(n * ratio))))
        if new_n == n:
            break
        n = new_n
    _, sim, secs, prims, n = min(tried, key=lambda x: x[0])
    return sim, secs, prims, n


def run_grids(
    cfg: ShapeConfig,
    targets: dict[str, list[Any]],
    guides: dict[str, str],
    summary: list[dict[str, Any]],
    log: Any = print,
) -> list[dict[str, Any]]:
    """Target | Reference | Guided | Unguided equal N | Unguided equal time, per test set."""
    from ngpm_runtime.image.render import render_array
    from ngpm_runtime.inference.guide import Guide

    from ngpm_compiler.language.compile import load_grammar

    program = load_grammar(cfg.grammar)
    guide = Guide.load(guides["all"], program)
    overall = [r for r in summary if r["dataset"] == "all"]
    header = [
        "Target",
        f"Reference (N = {cfg.reference_n})",
        f"Guided (N = {cfg.guided_n})",
        f"Unguided (N = {cfg.guided_n})",
        "Unguided (equal time)",
    ]
    rows_csv = []
    per_set = max(1, cfg.grid_targets // max(1, len(targets)))
    for ds, ts in targets.items():
        grid = []
        for ti, t in enumerate(pick(ts, per_set)):
            seed = run_seed(cfg.seed + 7, ti, 0, 0)
            size = 150
            cells = [{"image": plots.target_image(t.mask, size), "caption": t.name}]
            guided = grow_once(program, t, guide, cfg.guided_n, seed)
            equal = equal_time_run(
                program,
                t,
                guided[1],
                equal_time_n(overall, guided[1], cfg.guided_n),
                cfg.guided_n,
                seed,
            )
            runs = [
                ("reference", None, cfg.reference_n),
                ("guided", guide, cfg.guided_n),
                ("unguided_equal_n", None, cfg.guided_n),
                ("unguided_equal_time", None, equal[3]),
            ]
            for kind, prop, n in runs:
                if kind == "guided":
                    sim, secs, prims = guided
                elif kind == "unguided_equal_time":
                    sim, secs, prims = equal[:3]
                else:
                    sim, secs, prims = grow_once(program, t, prop, n, seed)
                img = render_array(prims, program.viewport, size, target_mask=t.mask)
                cells.append(
                    {"image": img, "caption": f"N = {n}, {plots.fmt_secs(secs)}\nsim {sim:.3f}"}
                )
                rows_csv.append(
                    {
                        "dataset": ds,
                        "target": t.name,
                        "kind": kind,
                        "n": n,
                        "seconds": round(secs, 4),
                        "similarity": round(sim, 4),
                        "primitives": len(prims),
                    }
                )
            grid.append(cells)
        path = Path(cfg.out) / f"grid_{ds}.png"
        plots.image_grid(grid, path, header=header)
        log(f"wrote {path}")
    write_csv(
        Path(cfg.out) / "grids.csv",
        rows_csv,
        ("dataset", "target", "kind", "n", "seconds", "similarity", "primitives"),
    )
    return rows_csv


def load_rows(cfg: ShapeConfig) -> list[dict[str, Any]]:
    return read_csv(Path(cfg.out) / "shape_runs.csv")


__all__ = [
    "RunTask",
    "analyze_shape",
    "load_rows",
    "prepare_guides",
    "run_grids",
    "run_shape",
    "test_targets",
    "tiny_traces",
]
