"""Evaluation core: SMC runs over (model, target, N, repeat), summary statistics, CSV files.

One *run* is SMC with N particles into one target; it records the best particle's normalized
similarity (the argument of the Gaussian of equation 1, `likelihood.similarity`; under the
circuit likelihood, whose targets are blank canvases giving the start, the argument of
equation 2, `likelihood.circuit_score`, in the same column) and the wall time of the SMC
call. Runs go to a backend (`jobs/backends.py`: worker processes, or Ray
tasks with `backend="ray"`) in a shuffled order, so a load change on the machine touches every
model alike. The statistics follow the paper: the median over repeats
per target, then the mean over targets with a 95% t interval.

Beside it in this package: held-out scoring (heldout) and its run cache (runcache), which
`ngpmc eval`, `ngpmc iterate` and `ngpmc tune` share; the studies of experiments/ build on it.
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from ngpm_runtime.files import atomic_write

from ngpm_compiler.jobs import backends, pool
from ngpm_compiler.jobs.driver import drive

if TYPE_CHECKING:  # targets loads PIL, grow the SMC: only in the workers that run
    from ngpm_runtime.geometry.turtle import Prim
    from ngpm_runtime.image.targets import Target
    from ngpm_runtime.inference.proposals import Proposal
    from ngpm_runtime.program import Program

RUN_FIELDS = (
    "model",
    "dataset",
    "target",
    "n",
    "repeat",
    "seed",
    "similarity",
    "seconds",
    "primitives",
)
SUMMARY_FIELDS = (
    "dataset",
    "model",
    "n",
    "targets",
    "mean_similarity",
    "ci_low",
    "ci_high",
    "mean_seconds",
    "median_seconds",
)
UNGUIDED = "unguided"


@dataclass(frozen=True)
class RunTask:
    model: str  # key into the worker's guides ("unguided" = prior proposals)
    dataset: str
    target: int  # index into the worker's target list
    n: int
    repeat: int
    seed: int


@dataclass
class RunResult:
    task: RunTask
    target_name: str
    similarity: float
    seconds: float
    primitives: list[Prim]

    def row(self) -> dict[str, Any]:
        t = self.task
        return {
            "model": t.model,
            "dataset": t.dataset,
            "target": self.target_name,
            "n": t.n,
            "repeat": t.repeat,
            "seed": t.seed,
            "similarity": round(self.similarity, 6),
            "seconds": round(self.seconds, 6),
            "primitives": len(self.primitives),
        }


def run_seed(base: int, target: int, n: int, repeat: int) -> int:
    """SMC seed of one run: the same for every model (common random numbers)."""
    return int(
        np.random.SeedSequence([int(base), int(target), int(n), int(repeat)]).generate_state(1)[0]
    )


def grow_once(
    program: Program,
    target: Target,
    proposal: Proposal | None,
    n: int,
    seed: int,
    likelihood: str = "shape",
) -> tuple[float, float, list[Prim]]:
    """SMC into `target`; (score of the best particle: similarity, or the circuit score,
    seconds, its primitives)."""
    from ngpm_runtime.grow import grow

    res = grow(program, target, proposal, n, seed, likelihood)
    return res.similarity, res.seconds, res.primitives


# --------------------------------------------------------------------------- workers


def _worker_setup(
    grammar: str,
    text: str,
    targets: dict[str, list[Target]],
    guides: dict[str, str | bytes],
    likelihood: str = "shape",
) -> dict[str, Any]:
    """A worker's state: the grammar from its text, the targets, and each guide from its path
    or, for workers that may be on other machines, from its file's bytes."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from ngpm_compiler.language.compile import load_grammar

    program = load_grammar(grammar, text)
    return {
        "program": program,
        "targets": targets,
        "guides": {name: backends.load_guide(g, program) for name, g in guides.items()},
        "likelihood": likelihood,
    }


def _run(task: RunTask) -> RunResult:
    w = pool.state()
    target = w["targets"][task.dataset][task.target]
    proposal = None if task.model == UNGUIDED else w["guides"][task.model]
    like = w.get("likelihood", "shape")
    sim, seconds, prims = grow_once(w["program"], target, proposal, task.n, task.seed, like)
    return RunResult(task, target.name, sim, seconds, prims)


def run_tasks(
    grammar: str,
    targets: dict[str, list[Target]],
    guides: dict[str, str],
    tasks: list[RunTask],
    workers: int = 1,
    shuffle_seed: int = 0,
    on_result: Callable[[RunResult], None] | None = None,
    backend: str = "local",
    address: str | None = None,
    likelihood: str = "shape",
) -> list[RunResult]:
    """Run every task (shuffled order, on `backend` with `workers` processes or Ray CPUs, or
    on the Ray cluster at `address`) under `likelihood`; results in task order."""
    order = np.random.default_rng(shuffle_seed).permutation(len(tasks))
    shuffled = [tasks[i] for i in order]
    ship = {name: backends.ship_file(path, backend) for name, path in guides.items()}
    text = Path(grammar).read_text(encoding="utf-8")
    jobs = backends.make_backend(
        backend, workers, _worker_setup, (grammar, text, targets, ship, likelihood), address
    )
    out: dict[RunTask, RunResult] = {}

    def keep(_: int, r: RunResult) -> None:
        if r.task not in out:  # else: a duplicate task
            out[r.task] = r
            if on_result:
                on_result(r)

    with jobs:
        drive(jobs, _run, enumerate(shuffled), keep)
    return [out[t] for t in tasks]


def shape_tasks(
    models: Iterable[str],
    datasets: dict[str, int],
    ns: Iterable[int],
    repeats: int,
    base_seed: int = 0,
) -> list[RunTask]:
    """Every (model, dataset target, N, repeat) combination; `datasets` maps name -> count."""
    tasks: list[RunTask] = []
    offset = 0
    for ds, count in datasets.items():
        for ti in range(count):
            for n in ns:
                for rep in range(repeats):
                    seed = run_seed(base_seed, offset + ti, n, rep)
                    tasks.extend(RunTask(m, ds, ti, int(n), rep, seed) for m in models)
        offset += count
    return tasks


def pick(items: list[Any], k: int) -> list[Any]:
    """k items spread evenly over the list (deterministic)."""
    if k >= len(items):
        return list(items)
    idx = np.unique(np.round(np.linspace(0, len(items) - 1, k)).astype(int))
    return [items[i] for i in idx]


# --------------------------------------------------------------------------- statistics


def t_central(t: float, df: int) -> float:
    """P(|T| < t) for Student's t with an integer `df` >= 1: the finite series of Abramowitz
    and Stegun 26.7.3-4 (exact up to rounding)."""
    theta = math.atan(t / math.sqrt(df))
    c2, s = math.cos(theta) ** 2, math.sin(theta)
    term = 1.0 if df % 2 == 0 else math.cos(theta)
    total = term if df % 2 == 0 or df > 1 else 0.0
    for k in range(2 if df % 2 == 0 else 3, df - 1, 2):
        term *= c2 * (k - 1) / k
        total += term
    if df % 2 == 0:
        return s * total
    return 2 / math.pi * (theta + s * total)


def t_quantile(p: float, df: int) -> float:
    """The `p` quantile (p > 0.5) of Student's t with integer `df`, by bisection on
    `t_central` (scipy.stats.t.ppf without scipy)."""
    level = 2 * p - 1
    lo, hi = 0.0, 1.0
    while t_central(hi, df) < level:
        lo, hi = hi, 2 * hi
    for _ in range(200):
        mid = (lo + hi) / 2
        if mid in (lo, hi):
            break
        lo, hi = (mid, hi) if t_central(mid, df) < level else (lo, mid)
    return (lo + hi) / 2


def t_interval(values: np.ndarray, level: float = 0.95) -> tuple[float, float, float]:
    """(mean, low, high): the mean with a Student-t confidence interval."""
    v = np.asarray(values, dtype=np.float64)
    m = float(v.mean())
    if len(v) < 2:
        return m, m, m
    half = t_quantile(0.5 + level / 2, len(v) - 1) * float(v.std(ddof=1)) / math.sqrt(len(v))
    return m, m - half, m + half


def summarize(rows: list[dict[str, Any]], dataset: str = "all") -> list[dict[str, Any]]:
    """Per (model, N): mean over targets of the per-target median similarity, 95% CI, times.

    `dataset` names the rows' test set in the output ("all" for every row given)."""
    groups: dict[tuple[str, int], dict[str, list[dict[str, Any]]]] = {}
    for r in rows:
        key = (str(r["model"]), int(r["n"]))
        groups.setdefault(key, {}).setdefault(f"{r['dataset']}/{r['target']}", []).append(r)
    out = []
    for (model, n), by_target in sorted(groups.items()):
        med = np.array(
            [np.median([float(x["similarity"]) for x in rs]) for rs in by_target.values()]
        )
        secs = np.array([float(x["seconds"]) for rs in by_target.values() for x in rs])
        mean, lo, hi = t_interval(med)
        out.append(
            {
                "dataset": dataset,
                "model": model,
                "n": n,
                "targets": len(med),
                "mean_similarity": round(mean, 6),
                "ci_low": round(lo, 6),
                "ci_high": round(hi, 6),
                "mean_seconds": round(float(secs.mean()), 6),
                "median_seconds": round(float(np.median(secs)), 6),
            }
        )
    return out


def curve(summary: list[dict[str, Any]], model: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N, mean similarity, mean seconds) of one model, by increasing N."""
    rows = sorted((r for r in summary if r["model"] == model), key=lambda r: r["n"])
    return (
        np.array([r["n"] for r in rows], dtype=np.int64),
        np.array([r["mean_similarity"] for r in rows], dtype=np.float64),
        np.array([r["mean_seconds"] for r in rows], dtype=np.float64),
    )


def time_to_reach(sims: np.ndarray, secs: np.ndarray, threshold: float) -> float:
    """Seconds a model needs to reach `threshold` similarity (nan if it never does).

    Walks the curve by increasing N and interpolates log-time linearly in similarity
    between the last point below the threshold and the first at or above it.
    """
    best_sim, prev_t = -math.inf, None
    for s, t in zip(sims, secs, strict=True):
        if s >= threshold:
            if prev_t is None or best_sim == -math.inf or s <= best_sim:
                return float(t)
            frac = (threshold - best_sim) / (s - best_sim)
            lt = math.log(max(prev_t, 1e-9)) + frac * (
                math.log(max(t, 1e-9)) - math.log(max(prev_t, 1e-9))
            )
            return float(min(math.exp(lt), t))
        if s > best_sim:
            best_sim, prev_t = s, t
    return math.nan


def speedups(
    summary: list[dict[str, Any]],
    models: list[str],
    thresholds: Iterable[float],
    baseline: str = UNGUIDED,
) -> list[dict[str, Any]]:
    """Rows (model, threshold, seconds, baseline_seconds, speedup) for Fig. 4b.

    Where the baseline never reaches a threshold, `speedup` is the lower bound given by its
    slowest run and `bound` is ">".
    """
    _, bs, bt = curve(summary, baseline)
    out = []
    for model in models:
        _, s, t = curve(summary, model)
        for thr in thresholds:
            tm = time_to_reach(s, t, thr)
            tb = time_to_reach(bs, bt, thr)
            bound = ""
            if math.isnan(tb) and not math.isnan(tm) and len(bt):
                tb, bound = float(bt.max()), ">"
            sp = tb / tm if not (math.isnan(tb) or math.isnan(tm)) and tm > 0 else math.nan
            out.append(
                {
                    "model": model,
                    "threshold": round(float(thr), 4),
                    "seconds": _r(tm),
                    "baseline_seconds": _r(tb),
                    "speedup": _r(sp),
                    "bound": bound,
                }
            )
    return out


def match_text(
    cross: float, t_reach: float, seconds: float, ns: np.ndarray, secs: np.ndarray
) -> tuple[str, str]:
    """How a benchmark states the baseline at equal similarity to a guided run of `seconds`
    (cross: n_to_match; t_reach: time_to_reach over the baseline's curve ns, secs): ("N ~
    329 in 0.373 s", "4.8x"), or where the baseline never reaches it a lower bound from its
    largest N: ("N > 1000 (1.110 s there)", "> 14.4x")."""
    if cross == cross and t_reach == t_reach:
        return f"N ~ {cross:.0f} in {t_reach:.3f} s", f"{t_reach / seconds:.1f}x"
    if not len(ns):
        return "no baseline runs", "?"
    top = int(np.argmax(ns))
    return f"N > {ns[top]} ({secs[top]:.3f} s there)", f"> {secs[top] / seconds:.1f}x"


def _r(x: float) -> float | str:
    return "" if math.isnan(x) else round(float(x), 6)


def n_to_match(summary: list[dict[str, Any]], similarity: float, baseline: str = UNGUIDED) -> float:
    """Smallest baseline N (log-interpolated) whose mean similarity reaches `similarity`."""
    ns, s, _ = curve(summary, baseline)
    v = time_to_reach(s, ns.astype(np.float64), similarity)
    return v


# --------------------------------------------------------------------------- files


def write_csv(path: str | Path, rows: list[dict[str, Any]], fields: Iterable[str]) -> Path:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(fields), lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: r.get(k, "") for k in w.fieldnames})
    return atomic_write(path, buf.getvalue().encode("utf-8"))


def read_csv(path: str | Path) -> list[dict[str, Any]]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))
