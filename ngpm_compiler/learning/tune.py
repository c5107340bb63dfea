"""`ngpmc tune`: choose how a trained guide proposes, on validation targets.

A guide's networks fix a proposal; its *settings* (ngpm_runtime ProposalSettings) sharpen or
flatten it (a temperature for choices, one for continuous values) and set when guided SMC
resamples (an ESS threshold). Every setting keeps the SMC weights exact. `tune` scores each
combination of a grid with guided SMC at N = 10 on validation targets (never the held-out
sets), keeps the best mean over the sets, and writes a copy of the guide whose metadata
holds it. Runs are cached in WORK/heldout_runs.csv, so an interrupted tune resumes.

Files in WORK: candidates/*.onnx (one guide per setting), heldout_runs.csv, heldout.csv,
tune.csv (a row per setting: per-set means and their mean), tune.md, source.txt.
"""

from __future__ import annotations

import hashlib
import itertools
from pathlib import Path
from typing import Any

import onnx
from ngpm_runtime.errors import NgpmError
from ngpm_runtime.files import atomic_write
from ngpm_runtime.inference.guide import PROPOSAL_KEY, ProposalSettings

from ngpm_compiler.evaluation.heldout import run_heldout
from ngpm_compiler.evaluation.runs import UNGUIDED, write_csv
from ngpm_compiler.progress import Log

TUNE_FIELDS = ["setting", "temperature", "choice_temperature", "ess_threshold"]


def grid(
    temperatures: tuple[float, ...],
    choice_temperatures: tuple[float, ...],
    ess: tuple[float | None, ...],
) -> list[ProposalSettings]:
    """Every combination in product order (ties in `tune` go to the earlier), duplicates
    dropped."""
    out = [
        ProposalSettings(t, c, e)
        for t, c, e in itertools.product(temperatures, choice_temperatures, ess)
    ]
    return sorted(set(out), key=out.index)


def name(s: ProposalSettings) -> str:
    """A file- and CSV-friendly name of one setting: T1_Tc0.3_ess0.5."""
    return s.label().replace("=", "").replace(",", "_")


def with_settings(src: str | Path, dst: str | Path, settings: ProposalSettings) -> Path:
    """Copy the guide `src` to `dst` (atomically) with `settings` in its metadata."""
    try:
        proto = onnx.load(str(src))
    except Exception:  # onnx raises several types for unreadable files
        raise NgpmError(f"{src}: not a readable ONNX guide") from None
    props = {p.key: p.value for p in proto.metadata_props}
    props[PROPOSAL_KEY] = settings.to_json()
    del proto.metadata_props[:]
    onnx.helper.set_model_props(proto, props)
    onnx.checker.check_model(proto)
    return atomic_write(dst, proto.SerializeToString())


def tune(
    grammar: str,
    guide: str,
    validation: dict[str, str],
    out: str | Path,
    work: str | Path,
    settings: list[ProposalSettings],
    k: int = 36,
    repeats: int = 5,
    workers: int = 2,
    seed: int = 0,
    log: Log = print,
    likelihood: str = "shape",
) -> dict[str, Any]:
    """Score every setting on `validation` (guided N = 10, k targets per set or all of a
    smaller set, `repeats` runs) under `likelihood` (circuit: validation is
    heldout.CIRCUIT_SETS, k blank canvases scored by equation 2's argument), write `out`
    with the best; returns {"best", "rows", "table"}."""
    work = Path(work)
    digest = hashlib.sha256(Path(guide).read_bytes()).hexdigest()
    atomic_write(work / "source.txt", f"{digest} {guide}\n")
    paths = {
        name(s): str(with_settings(guide, work / "candidates" / f"{name(s)}.onnx", s))
        for s in settings
    }
    res = run_heldout(
        work,
        grammar,
        validation,
        paths,
        k=k,
        repeats=repeats,
        guided_n=10,
        unguided_ns=(),
        workers=workers,
        seed=seed,
        log=log,
        likelihood=likelihood,
    )
    sets = sorted(validation)
    means = {(r["model"], r["dataset"]): float(r["mean_similarity"]) for r in res["summary"]}
    spread = {
        (r["model"], r["dataset"]): (float(r["ci_high"]) - float(r["ci_low"])) / 2
        for r in res["summary"]
    }
    counts = {str(r["dataset"]): int(r["targets"]) for r in res["summary"]}
    rows = []
    for s in settings:
        row: dict[str, Any] = {
            "setting": name(s),
            "temperature": s.temperature,
            "choice_temperature": s.choice_temperature,
            "ess_threshold": s.ess_threshold,
        }
        for d in sets:
            row[d] = round(means[(name(s), d)], 4)
            row[f"{d}_ci95"] = round(spread[(name(s), d)], 4)
        row["mean"] = round(sum(means[(name(s), d)] for d in sets) / len(sets), 4)
        rows.append(row)
    baseline = {d: (means[(UNGUIDED, d)], spread[(UNGUIDED, d)]) for d in sets}
    best_row = max(rows, key=lambda r: r["mean"])  # the first of equals: grid order
    best = settings[rows.index(best_row)]
    write_csv(work / "tune.csv", rows, [*TUNE_FIELDS, *sets, *(f"{d}_ci95" for d in sets), "mean"])
    score = "circuit score (eq. 2's argument)" if likelihood == "circuit" else "similarity"
    table = tune_table(rows, sets, best_row["setting"], counts, repeats, baseline, score)
    atomic_write(work / "tune.md", table)
    with_settings(guide, out, best)
    return {"best": best, "rows": rows, "table": table}


def tune_table(
    rows: list[dict[str, Any]],
    sets: list[str],
    best: str,
    counts: dict[str, int],
    repeats: int,
    baseline: dict[str, tuple[float, float]] | None = None,
    score: str = "similarity",
) -> str:
    """Markdown: one row per setting, the chosen one in bold, each set's mean +- the half
    width of its 95% interval over targets when known; `counts`: targets per set;
    `baseline`: unguided SMC's (mean, half width) per set at the same N."""
    if len({counts[d] for d in sets}) == 1:
        per_set = f"{counts[sets[0]]} targets per set"
    else:
        per_set = "targets per set: " + ", ".join(f"{d} {counts[d]}" for d in sets)
    lines = [
        f"Guided SMC, N = 10, {per_set}, {repeats} runs each: mean over "
        f"targets of the median {score} (+- half the 95% interval over targets).",
        "",
        "| temperature | choice temperature | ESS threshold | " + " | ".join(sets) + " | mean |",
        "|---" * (4 + len(sets)) + "|",
    ]

    def cell(mean: float, half: float | None) -> str:
        return f"{mean:.3f}" if half is None else f"{mean:.3f} +- {half:.3f}"

    for r in rows:
        ess = "none" if r["ess_threshold"] is None else f"{r['ess_threshold']:g}"
        cells = [
            f"{r['temperature']:g}",
            f"{r['choice_temperature']:g}",
            ess,
            *(cell(r[d], r.get(f"{d}_ci95")) for d in sets),
            f"{r['mean']:.3f}",
        ]
        if r["setting"] == best:
            cells = [f"**{c}**" for c in cells]
        lines.append("| " + " | ".join(cells) + " |")
    if baseline:
        mean = sum(baseline[d][0] for d in sets) / len(sets)
        lines.append(
            "| unguided SMC, N = 10 | | | "
            + " | ".join(cell(*baseline[d]) for d in sets)
            + f" | {mean:.3f} |"
        )
    return "\n".join(lines) + "\n"
