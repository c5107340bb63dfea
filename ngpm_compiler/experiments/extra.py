"""The circuit study (vines under equation 2, no target) and the chain of paper Figure 1.

Circuit: traces are the best particles of unguided SMC under CircuitLikelihood, written as
a traces directory that `traces.load_traces` reads, so experiments.models trains on them as usual.
Score of a result: the argument of equation 2's Gaussian, edge(I) * (1 - relerr(fill(I))).
Files: circuit_runs.csv, circuit.png.

Chain: smooth arcs as targets (drawn from the chain's own geometry), unguided SMC traces on
training arcs, an all-features guide, then forward (prior) samples, unguided and guided SMC
and guide-only samples on held-out arcs. Files: chain_runs.csv, chain.png.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ngpm_compiler.evaluation.runs import grow_once, run_seed, t_interval, write_csv
from ngpm_compiler.experiments import plots
from ngpm_compiler.experiments.config import ChainConfig, CircuitConfig
from ngpm_compiler.experiments.models import ModelSpec, train_models
from ngpm_compiler.jobs import pool

if TYPE_CHECKING:
    from ngpm_runtime.image.targets import Target
    from ngpm_runtime.inference.guide import Guide
    from ngpm_runtime.program import Program

# --------------------------------------------------------------------------- circuit

CIRCUIT_SIZE = (50, 50)


def circuit_start(viewport: tuple[float, ...]) -> tuple[float, float, float]:
    """Bottom middle of the viewport, heading up (grow.circuit_target's start)."""
    xmin, xmax, ymin, ymax = viewport
    return (xmin + xmax) / 2.0, ymin + 0.05 * (ymax - ymin), 90.0


def circuit_once(
    program: Any, proposal: Any, n: int, seed: int, record: bool = False
) -> tuple[float, float, Any]:
    """SMC under the circuit likelihood; (score of the best particle, seconds, best)."""
    from ngpm_runtime.grow import grow
    from ngpm_runtime.inference.smc import TraceRecording

    trace = TraceRecording.FULL if record else TraceRecording.NONE
    res = grow(
        program,
        None,
        proposal,
        n,
        seed,
        "circuit",
        trace=trace,
        start=circuit_start(program.viewport),
        canvas_size=CIRCUIT_SIZE,
    )
    return res.similarity, res.seconds, res.smc.best  # circuit_score of its image


def _circuit_setup(grammar: str) -> dict[str, Any]:
    from ngpm_compiler.language.compile import load_grammar

    return {"program": load_grammar(grammar)}


def _circuit_job(args: tuple[int, int, int]) -> dict[str, np.ndarray]:
    from ngpm_compiler.learning.trace_jobs import PAPER_MIN_PRIMITIVES, job_arrays

    job, base_seed, particles = args
    seed = run_seed(base_seed, job, particles, 99)
    _, _, best = circuit_once(pool.state()["program"], None, particles, seed, record=True)
    n_prims = len(best.primitives)
    kept = n_prims >= PAPER_MIN_PRIMITIVES
    return job_arrays(job, 0, seed, list(best.trace or []), n_prims, kept)


def circuit_traces(cfg: CircuitConfig, out_dir: str, log: Any = print) -> str:
    """Unguided circuit-SMC traces (kept: >= 10 primitives) as a traces directory."""
    from ngpm_compiler.language.compile import load_grammar
    from ngpm_compiler.learning.trace_jobs import site_layouts
    from ngpm_compiler.learning.trace_store import TRACE_FORMAT, TraceStore, merge_arrays, save_npz

    store = TraceStore(out_dir)
    m = store.manifest()
    if m and m.get("kept", 0) >= cfg.circuit_traces and m["key"].get("circuit"):
        return out_dir
    store.dir.mkdir(parents=True, exist_ok=True)
    for p in store.shard_paths():
        p.unlink()
    program = load_grammar(cfg.grammar)
    t0 = time.perf_counter()
    parts: list[dict[str, np.ndarray]] = []
    kept, job = 0, 0
    with pool.spawn_pool(max(1, cfg.workers), _circuit_setup, (cfg.grammar,)) as procs:
        while kept < cfg.circuit_traces:
            batch = [
                (j, cfg.seed, cfg.circuit_particles)
                for j in range(job, job + max(4, cfg.circuit_traces - kept))
            ]
            job += len(batch)
            for arr in procs.imap(_circuit_job, batch):
                if bool(arr["kept"][0]) and kept < cfg.circuit_traces:
                    kept += 1
                    parts.append(arr)
            log(f"circuit traces: {kept}/{cfg.circuit_traces} kept after {job} jobs")
            if job > 20 * cfg.circuit_traces + 20:
                break
    if parts:
        save_npz(store.dir / "shard_00000000.npz", merge_arrays(parts))
    layouts = site_layouts(program, None)
    store.write_manifest(
        {
            "format": TRACE_FORMAT,
            "key": {
                "grammar": program.name,
                "grammar_hash": program.grammar_hash,
                "circuit": True,
                "particles": cfg.circuit_particles,
                "seed": cfg.seed,
            },
            "grammar_hash": program.grammar_hash,
            "sites": [s.to_json() for s in program.sites],
            "layouts": {
                str(i): {g: [sl.start, sl.stop] for g, sl in lay.items()}
                for i, lay in layouts.items()
            },
            "kept": kept,
            "jobs_done": job,
            "dropped": job - kept,
            "seconds": time.perf_counter() - t0,
            "shards": [p.name for p in store.shard_paths()],
        }
    )
    return out_dir


def run_circuit(cfg: CircuitConfig, log: Any = print) -> list[dict[str, Any]]:
    """Traces, a guide, then reference / guided / unguided equal N / equal time runs."""
    from ngpm_runtime.image.render import render_array
    from ngpm_runtime.inference.guide import Guide

    from ngpm_compiler.language.compile import load_grammar

    work = Path(cfg.work)
    traces = circuit_traces(cfg, str(work / "circuit_traces"), log)
    spec = ModelSpec("circuit_all", "all", 4, None, cfg.epochs)
    path = train_models([spec], traces, str(work / "models"), 1, cfg.seed)["circuit_all"]
    program = load_grammar(cfg.grammar)
    guide = Guide.load(path, program)
    rows: list[dict[str, Any]] = []
    examples: dict[str, tuple[float, float, Any, int]] = {}
    kinds = [
        ("reference", None, cfg.circuit_reference_n),
        ("guided", guide, cfg.circuit_guided_n),
        ("unguided_equal_n", None, cfg.circuit_guided_n),
    ]
    for rep in range(cfg.circuit_repeats):
        seed = run_seed(cfg.seed + 11, rep, 0, 0)
        guided_secs = 0.0
        for kind, prop, n in kinds:
            score, secs, best = circuit_once(program, prop, n, seed)
            guided_secs = secs if kind == "guided" else guided_secs
            rows.append(_crow(kind, n, rep, seed, score, secs, best))
            if rep == 0:
                examples[kind] = (score, secs, best, n)
        # equal time: unguided N scaled from the equal-N run's time
        eq = [r for r in rows if r["repeat"] == rep and r["kind"] == "unguided_equal_n"][0]
        n_eq = max(
            cfg.circuit_guided_n,
            int(round(cfg.circuit_guided_n * guided_secs / max(eq["seconds"], 1e-6))),
        )
        score, secs, best = circuit_once(program, None, n_eq, seed)
        rows.append(_crow("unguided_equal_time", n_eq, rep, seed, score, secs, best))
        if rep == 0:
            examples["unguided_equal_time"] = (score, secs, best, n_eq)
    write_csv(
        Path(cfg.out) / "circuit_runs.csv",
        rows,
        ("kind", "n", "repeat", "seed", "score", "seconds", "primitives"),
    )
    titles = {
        "reference": "Reference",
        "guided": "Guided",
        "unguided_equal_n": "Unguided (equal N)",
        "unguided_equal_time": "Unguided (equal time)",
    }
    cells = []
    for kind in titles:
        score, secs, best, n = examples[kind]
        img = render_array(list(best.primitives), program.viewport, 170)
        cells.append(
            {"image": img, "caption": f"N = {n}, {plots.fmt_secs(secs)}\nscore {score:.3f}"}
        )
    plots.image_grid([cells], Path(cfg.out) / "circuit.png", cell=2.2, header=list(titles.values()))
    return rows


def _crow(
    kind: str, n: int, rep: int, seed: int, score: float, secs: float, best: Any
) -> dict[str, Any]:
    return {
        "kind": kind,
        "n": n,
        "repeat": rep,
        "seed": seed,
        "score": round(score, 5),
        "seconds": round(secs, 4),
        "primitives": len(best.primitives),
    }


def circuit_table(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per kind: mean N, mean score (95% CI), mean seconds."""
    out = []
    for kind in ("reference", "guided", "unguided_equal_n", "unguided_equal_time"):
        rs = [r for r in rows if r["kind"] == kind]
        if not rs:
            continue
        m, lo, hi = t_interval(np.array([float(r["score"]) for r in rs]))
        out.append(
            {
                "kind": kind,
                "n": float(np.mean([float(r["n"]) for r in rs])),
                "score": m,
                "ci_low": lo,
                "ci_high": hi,
                "seconds": float(np.mean([float(r["seconds"]) for r in rs])),
                "runs": len(rs),
            }
        )
    return out


# --------------------------------------------------------------------------- chain


def chain_arc(
    rng: np.random.Generator, program: Any, size: int = 50, links: int = 12, name: str = "arc"
) -> Any:
    """A smooth arc drawn like the chain (links of length 1 with slowly varying turns)."""
    from ngpm_runtime.image.raster import rasterize
    from ngpm_runtime.image.targets import Target

    vp = program.viewport
    x, y, h = program.start
    a, b = rng.uniform(-14, 14), rng.uniform(-16, 16)
    prims = []
    for i in range(links):
        h += a + b * (i / links - 0.5)
        nx, ny = x + math.cos(math.radians(h)), y + math.sin(math.radians(h))
        prims.append(("seg", x, y, nx, ny, 1.0))
        x, y = nx, ny
    mask = rasterize(prims, vp, size, size).astype(bool)
    xmin, xmax, ymin, ymax = vp
    sx, sy, sh = program.start
    start = (
        (sx - xmin) / (xmax - xmin),
        (ymax - sy) / (ymax - ymin),
        math.cos(math.radians(sh)),
        -math.sin(math.radians(sh)),
    )
    return Target(mask, start, name)


def run_chain(cfg: ChainConfig, log: Any = print) -> list[dict[str, Any]]:
    """Chain of Figure 1: prior samples, unguided vs guided SMC, guide samples."""
    from ngpm_runtime.inference.guide import Guide

    from ngpm_compiler.language.compile import load_grammar
    from ngpm_compiler.learning.trace_jobs import PAPER_MIN_PRIMITIVES
    from ngpm_compiler.learning.traces import TraceConfig, generate_traces

    work = Path(cfg.work) / "chain"
    program = load_grammar(cfg.chain_grammar)
    rng = np.random.default_rng(cfg.seed + 5)
    arcs = [
        chain_arc(rng, program, name=f"arc_{i:03d}")
        for i in range(cfg.chain_train_targets + cfg.chain_test_targets)
    ]
    train, test = arcs[: cfg.chain_train_targets], arcs[cfg.chain_train_targets :]
    tdir = work / "targets"
    if not tdir.is_dir():
        from ngpm_runtime.image.targets import save_target

        tdir.mkdir(parents=True)
        for t in train:
            save_target(t, tdir / f"{t.name}.png")
    traces = work / "traces"
    generate_traces(
        TraceConfig(
            grammar=cfg.chain_grammar,
            targets=str(tdir),
            n=cfg.chain_traces,
            particles=cfg.chain_particles,
            seed=cfg.seed,
            workers=max(1, cfg.workers),
            min_primitives=PAPER_MIN_PRIMITIVES,  # the paper's evaluation
            backend=cfg.backend,
            ray_address=cfg.ray_address,
        ),
        traces,
        progress=False,
    )
    spec = ModelSpec("chain_all", "all", 4, None, cfg.epochs)
    path = train_models([spec], str(traces), str(work / "models"), 1, cfg.seed)["chain_all"]
    guide = Guide.load(path, program)
    log(f"chain guide: {path}")
    rows = []
    for ti, t in enumerate(test):
        for n in cfg.chain_ns:
            for rep in range(cfg.chain_repeats):
                seed = run_seed(cfg.seed + 3, ti, n, rep)
                for model, prop in (("unguided", None), ("guided", guide)):
                    sim, secs, prims = grow_once(program, t, prop, n, seed)
                    rows.append(
                        {
                            "model": model,
                            "target": t.name,
                            "n": n,
                            "repeat": rep,
                            "similarity": round(sim, 5),
                            "seconds": round(secs, 5),
                        }
                    )
    write_csv(
        Path(cfg.out) / "chain_runs.csv",
        rows,
        ("model", "target", "n", "repeat", "similarity", "seconds"),
    )
    _chain_figure(cfg, program, test, guide)
    return rows


def _chain_figure(cfg: ChainConfig, program: Program, test: list[Target], guide: Guide) -> None:
    """chain.png: per test target, the target, prior samples, unguided and guided SMC, and
    guide samples (N = 1)."""
    from ngpm_runtime.image.render import render_array
    from ngpm_runtime.inference.smc import forward

    size, n_show = 150, 8
    vp = program.viewport
    assert vp is not None  # the chain grammar has one; its traces were drawn through it
    grid = []
    n_smc = max(cfg.chain_ns)
    for ti, t in enumerate(test):
        start = t.start_pose(vp)
        prior = [p for s in range(n_show) for p in forward(program, seed=s, start=start).primitives]
        gs = [p for s in range(n_show) for p in grow_once(program, t, guide, 1, 1000 + s)[2]]
        cells = [
            {"image": plots.target_image(t.mask, size), "caption": t.name},
            {
                "image": render_array(prior, vp, size, target_mask=t.mask),
                "caption": f"{n_show} prior samples",
            },
        ]
        for label, prop in (("unguided", None), ("guided", guide)):
            sim, secs, prims = grow_once(program, t, prop, n_smc, run_seed(cfg.seed, ti, 0, 1))
            cells.append(
                {
                    "image": render_array(prims, vp, size, target_mask=t.mask),
                    "caption": f"{label} SMC N = {n_smc}\nsim {sim:.3f}, {plots.fmt_secs(secs)}",
                }
            )
        cells.append(
            {
                "image": render_array(gs, vp, size, target_mask=t.mask),
                "caption": f"{n_show} guided samples (N = 1)",
            }
        )
        grid.append(cells)
    plots.image_grid(
        grid,
        Path(cfg.out) / "chain.png",
        header=["Target", "Forward (prior)", "Unguided SMC", "Guided SMC", "Guide samples"],
    )


def chain_table(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out = []
    for n in sorted({int(r["n"]) for r in rows}):
        for model in ("unguided", "guided"):
            rs = [r for r in rows if int(r["n"]) == n and r["model"] == model]
            by_t: dict[str, list[float]] = {}
            for r in rs:
                by_t.setdefault(r["target"], []).append(float(r["similarity"]))
            med = np.array([np.median(v) for v in by_t.values()])
            m, lo, hi = t_interval(med)
            out.append(
                {
                    "model": model,
                    "n": n,
                    "similarity": m,
                    "ci_low": lo,
                    "ci_high": hi,
                    "seconds": float(np.mean([float(r["seconds"]) for r in rs])),
                }
            )
    return out
