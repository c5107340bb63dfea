"""Held-out evaluation: guides at N = 10 against unguided SMC at several N on target sets
that no training target comes from (script glyphs, clip-art silhouettes).

Runs are cached in `heldout_runs.csv` of the results directory, one line appended as each
run finishes (evaluation/runcache.py), so an interrupted call resumes where it stopped. A
run is keyed by (model, set, target, N, repeat, seed) and by the content hashes of the
guide file (which holds its proposal settings), of the loaded target (mask and start) and
of the grammar file, so a later call with another guide only runs what is new (unguided
runs, which do not depend on the guide, are measured once), and a guide, target or grammar
changed under the same name is run again, never served from the cache. Files written:
- heldout_runs.csv    one row per SMC run (runs.RUN_FIELDS, then guide_sha, target_sha,
                      grammar_sha: the first 16 hex digits of sha256; guide_sha is empty for
                      unguided runs)
- heldout.csv         per set, model and N: mean of per-target medians, 95% CI, seconds
- heldout.md          the table: guided N = 10 vs unguided N, crossing N, losses per target
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from ngpm_runtime.files import atomic_write

from ngpm_compiler.evaluation.runcache import append_run, read_runs
from ngpm_compiler.evaluation.runs import (
    RUN_FIELDS,
    SUMMARY_FIELDS,
    UNGUIDED,
    RunResult,
    RunTask,
    n_to_match,
    pick,
    run_seed,
    run_tasks,
    summarize,
    write_csv,
)
from ngpm_compiler.progress import Log

if TYPE_CHECKING:  # targets loads PIL: only when targets are loaded
    from ngpm_runtime.image.targets import Target
    from ngpm_runtime.program import Program

RUNS_FILE = "heldout_runs.csv"
# the validation "set" of the circuit likelihood: k blank canvases (grow.circuit_target),
# which differ only in their runs' seeds; its directory is not read
CIRCUIT_SETS = {"circuit": ""}
HASH_FIELDS = ("guide_sha", "target_sha", "grammar_sha")
HELDOUT_FIELDS = (*RUN_FIELDS, *HASH_FIELDS)


def parse_pairs(text: str) -> dict[str, str]:
    """'a=x,b=y' -> {'a': 'x', 'b': 'y'} (a bare 'x' is named after its file stem)."""
    out = {}
    for part in (p.strip() for p in text.split(",") if p.strip()):
        name, _, value = part.partition("=")
        if not value:
            name, value = Path(part).stem, part
        out[name.strip()] = value.strip()
    return out


def load_sets(
    sets: dict[str, str], k: int, program: Program | None = None, likelihood: str = "shape"
) -> dict[str, list[Any]]:
    """k targets of each set, spread evenly over the set's sorted files (no mirrors); for
    a 3D `program`, 3D target sets (`ngpmc targets build`) placed in its box; under the
    circuit likelihood, k blank canvases per set (`grow.circuit_target`, named circuit_<i>)."""
    from ngpm_runtime.image.targets import Target, load_dataset

    if likelihood == "circuit":
        from ngpm_runtime.grow import circuit_target

        blank = circuit_target()
        return {
            name: [Target(blank.mask, blank.start, f"circuit_{i:02d}") for i in range(k)]
            for name in sets
        }

    if program is not None and program.dim == 3:
        from ngpm_runtime.volume.load import load_volume_dataset

        return {
            name: pick([t for t in load_volume_dataset(d, program) if not t.name.endswith("_m")], k)
            for name, d in sets.items()
        }
    return {
        name: pick([t for t in load_dataset(d, size=50) if not t.name.endswith("_m")], k)
        for name, d in sets.items()
    }


def heldout_tasks(
    targets: dict[str, list[Target]],
    guides: list[str],
    guided_n: int,
    unguided_ns: tuple[int, ...],
    repeats: int,
    base_seed: int = 0,
) -> list[RunTask]:
    """Every guide at `guided_n` and unguided SMC at `guided_n` and `unguided_ns`; a run's
    seed depends on (set, target, N, repeat) only, so models share random numbers."""
    tasks = []
    for si, (name, ts) in enumerate(sorted(targets.items())):
        for ti in range(len(ts)):
            for rep in range(repeats):
                for n in sorted({guided_n, *unguided_ns}):
                    seed = run_seed(base_seed + 1000 * (si + 1), ti, n, rep)
                    tasks.append(RunTask(UNGUIDED, name, ti, n, rep, seed))
                    if n == guided_n:
                        tasks.extend(RunTask(g, name, ti, n, rep, seed) for g in guides)
    return tasks


def short_hash(data: bytes) -> str:
    """The first 16 hex digits of sha256: a content hash for the run cache."""
    return hashlib.sha256(data).hexdigest()[:16]


def target_hash(target: Any) -> str:
    """Content hash of a loaded target: what a run sees of it, its mask (a 3D target's
    occupancy) and start."""
    grid = getattr(target, "occupancy", None)
    mask = np.ascontiguousarray(target.mask if grid is None else grid, dtype=bool)
    shape_start = repr((mask.shape, tuple(float(v) for v in target.start))).encode()
    return short_hash(shape_start + np.packbits(mask).tobytes())


def run_ids(
    tasks: list[RunTask], targets: dict[str, list[Target]], grammar: str, guides: dict[str, str]
) -> dict[RunTask, dict[str, Any]]:
    """Each task's cache identity: the key columns of its row in heldout_runs.csv."""
    grammar_sha = short_hash(Path(grammar).read_bytes())
    guide_sha = {name: short_hash(Path(path).read_bytes()) for name, path in guides.items()}
    target_sha = {
        (name, i): target_hash(t) for name, ts in targets.items() for i, t in enumerate(ts)
    }
    return {
        t: {
            "model": t.model,
            "dataset": t.dataset,
            "target": targets[t.dataset][t.target].name,
            "n": t.n,
            "repeat": t.repeat,
            "seed": t.seed,
            "guide_sha": guide_sha.get(t.model, ""),
            "target_sha": target_sha[(t.dataset, t.target)],
            "grammar_sha": grammar_sha,
        }
        for t in tasks
    }


def _key(row: dict[str, Any]) -> tuple[Any, ...]:
    return (
        str(row["model"]),
        str(row["dataset"]),
        str(row["target"]),
        int(row["n"]),
        int(row["repeat"]),
        int(row["seed"]),
        *(str(row[f]) for f in HASH_FIELDS),
    )


def run_heldout(
    out: str | Path,
    grammar: str,
    sets: dict[str, str],
    guides: dict[str, str],
    k: int = 16,
    repeats: int = 3,
    guided_n: int = 10,
    unguided_ns: tuple[int, ...] = (200, 600, 2000),
    workers: int = 2,
    seed: int = 0,
    log: Log = print,
    likelihood: str = "shape",
) -> dict[str, Any]:
    """Run what `heldout_runs.csv` lacks, then write the summary and table (under the
    circuit likelihood `sets` names the sets of blank canvases: CIRCUIT_SETS)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    runs_path = out / RUNS_FILE
    from ngpm_compiler.language.compile import load_grammar

    targets = load_sets(sets, k, load_grammar(grammar), likelihood)
    tasks = heldout_tasks(targets, list(guides), guided_n, unguided_ns, repeats, seed)
    ids = run_ids(tasks, targets, grammar, guides)
    have = {_key(r): r for r in read_runs(runs_path, HELDOUT_FIELDS, log)}
    todo = [t for t in tasks if _key(ids[t]) not in have]
    log(f"held-out: {len(tasks)} runs, {len(todo)} to do")
    if todo:
        todo_args = (todo, ids, have, workers, seed, log, likelihood)
        _run_todo(runs_path, grammar, targets, guides, *todo_args)
    rows = [have[_key(ids[t])] for t in tasks]
    summary = [
        s
        for name in sorted(targets)
        for s in summarize([r for r in rows if r["dataset"] == name], name)
    ]
    write_csv(out / "heldout.csv", summary, SUMMARY_FIELDS)
    table = heldout_table(rows, summary, list(guides), guided_n)
    atomic_write(out / "heldout.md", table.encode("utf-8"))
    return {"rows": rows, "summary": summary, "table": table}


def _run_todo(
    runs_path: Path,
    grammar: str,
    targets: dict[str, list[Target]],
    guides: dict[str, str],
    todo: list[RunTask],
    ids: dict[RunTask, dict[str, Any]],
    have: dict[tuple[Any, ...], dict[str, str]],
    workers: int,
    seed: int,
    log: Log,
    likelihood: str = "shape",
) -> None:
    """Run `todo`, appending each run to `runs_path` (and to `have`) as it finishes."""
    done = 0
    with open(runs_path, "a", encoding="utf-8", newline="") as fh:

        def note(r: RunResult) -> None:
            nonlocal done
            row = append_run(fh, {**r.row(), **ids[r.task]}, HELDOUT_FIELDS)
            have[_key(row)] = row
            done += 1
            if done % 50 == 0:
                log(f"held-out: {done}/{len(todo)} runs")

        run_tasks(
            grammar,
            targets,
            guides,
            todo,
            workers=workers,
            shuffle_seed=seed,
            on_result=note,
            likelihood=likelihood,
        )


def losses(rows: list[dict[str, Any]], model: str, dataset: str, guided_n: int) -> list[str]:
    """Targets where `model`'s median similarity over repeats is below unguided's, same N."""

    def medians(m: str) -> dict[str, float]:
        by: dict[str, list[float]] = {}
        for r in rows:
            if r["model"] == m and r["dataset"] == dataset and int(r["n"]) == guided_n:
                by.setdefault(str(r["target"]), []).append(float(r["similarity"]))
        return {t: float(np.median(v)) for t, v in by.items()}

    g, u = medians(model), medians(UNGUIDED)
    return sorted(t for t in g if t in u and g[t] < u[t])


def heldout_table(
    rows: list[dict[str, Any]], summary: list[dict[str, Any]], guides: list[str], guided_n: int
) -> str:
    """Markdown: per set, each model's mean similarity at each N, the unguided N that
    matches the guide at `guided_n`, and the targets where the guide loses to unguided."""
    lines = []
    for ds in sorted({s["dataset"] for s in summary}):
        sub = [s for s in summary if s["dataset"] == ds]
        uns = sorted({int(s["n"]) for s in sub if s["model"] == UNGUIDED})
        n_t = max(int(s["targets"]) for s in sub)
        lines += [
            f"**{ds}** ({n_t} targets)",
            "",
            "| model | "
            + " | ".join(f"unguided N={n}" for n in uns)
            + f" | guided N={guided_n} | unguided N to match | targets guided < "
            f"unguided (N={guided_n}) |",
            "|---" * (len(uns) + 4) + "|",
        ]
        ung = {int(s["n"]): float(s["mean_similarity"]) for s in sub if s["model"] == UNGUIDED}
        for g in guides:
            row = [s for s in sub if s["model"] == g and int(s["n"]) == guided_n]
            if not row:
                continue
            sim = float(row[0]["mean_similarity"])
            match = n_to_match(sub, sim)
            m = f">{max(uns)}" if math.isnan(match) else f"{match:.0f}"
            lost = losses(rows, g, ds, guided_n)
            lines.append(
                f"| {g} | "
                + " | ".join(f"{ung[n]:.3f}" for n in uns)
                + f" | {sim:.3f} | {m} | {len(lost)}"
                + (f" ({', '.join(lost)})" if lost else "")
                + " |"
            )
        lines.append("")
    return "\n".join(lines)
