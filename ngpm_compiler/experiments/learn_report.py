"""OUT/report.md of `ngpmc learn` (and OUT/curve.png): validation similarity per round,
wall time per stage, the budget plan and its reasons, the tuning table, and similarity vs N
of the guide and of unguided SMC on the validation targets. Written from learn.json's
state alone, so a stopped run's report shows what finished."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ngpm_runtime.files import atomic_write

from ngpm_compiler.evaluation.runs import UNGUIDED, n_to_match

NOT_TUNED = "Not tuned (no grid in the plan, or no budget left)."


# under the circuit likelihood the report's "similarity" is the circuit score
CIRCUIT_NOTE = (
    "Likelihood: circuit (equation 2). Every similarity below is the circuit score, "
    "equation 2's argument of the best particle, on blank canvases grown from the bottom "
    "middle (1 is the optimum).",
    "",
)


def _min(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.1f} min"


def rounds_table(rounds: list[dict[str, Any]], best: int | None) -> list[str]:
    lines = [
        "| round | teacher | traces trained on | validation NLL | validation similarity "
        "(N = 10) | traces | training | validation |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rounds:
        s = r["seconds"]
        sim = f"{r['validation']:.3f}"
        lines.append(
            f"| {r['round']}{' (best)' if r['round'] == best else ''} | {r['teacher']} | "
            f"{r['traces']} | {r['val_nll']} | {f'**{sim}**' if r['round'] == best else sim} | "
            f"{_min(s['traces'])} | {_min(s['train'])} | {_min(s['validation'])} |"
        )
    return lines


def measured(c: dict[str, Any]) -> str:
    """The measured costs, in words."""
    out = f"Measured: unguided trace jobs {1000 * c.get('unguided', 0):.2f} ms per particle"
    if "guided" in c:
        out += f", guided {1000 * c['guided']:.2f} ms"
    if "val_run" in c:
        out += f"; a guided run at N = 10 {c['val_run']:.2f} s"
    if "train" in c:
        out += f"; training {c['train']:.3f} s per trace"
    return out + " (one worker)."


def plan_lines(state: dict[str, Any]) -> list[str]:
    stages = state["stages"]
    p = (stages.get("replan") or stages.get("plan") or {}).get("result")
    if p is None:
        return ["No plan was made (the run stopped before)."]
    c = state.get("costs", {})
    lines = [
        f"Planned for {_min(p['budget'])} (what was left after the diagnosis, the "
        f"targets and the measurement). {measured(c)}",
        "",
        f"- round 0: {p['traces']} traces from unguided SMC with {p['unguided_particles']} "
        f"particles; then up to {p['rounds']} guided round(s) of {p['guided_traces']} traces with "
        f"{p['guided_particles']} particles, each trained on every round's traces",
        f"- validation: {p['val_targets']} targets per set, {p['val_repeats']} run(s) each",
        "- tune grid: "
        + (
            "choice temperatures "
            + ", ".join(f"{t:g}" for t in p["choice_temperatures"])
            + "; ESS thresholds "
            + ", ".join("none" if e is None else f"{e:g}" for e in p["ess"])
            if p["choice_temperatures"]
            else "none"
        ),
        "- estimates: " + ", ".join(f"{k} {_min(v)}" for k, v in p["estimates"].items()),
        "",
        "Why:",
        "",
        *(f"- {r}" for r in p["reasons"]),
    ]
    return lines


def curve_lines(summary: list[dict[str, Any]] | None, out: Path) -> list[str]:
    """The curve's table and plot (PNG unless matplotlib is missing)."""
    if not summary:
        return ["The curve was not measured (the run stopped before it)."]
    guided = {int(r["n"]): r for r in summary if r["model"] == "guide"}
    unguided = {int(r["n"]): r for r in summary if r["model"] == UNGUIDED}
    lines = [
        "| N | guided | unguided | guided seconds | unguided seconds |",
        "|---|---|---|---|---|",
    ]

    def cell(row: dict[str, Any] | None, key: str, fmt: str) -> str:
        return format(float(row[key]), fmt) if row else ""

    for n in sorted({*guided, *unguided}):
        g, u = guided.get(n), unguided.get(n)
        cells = [
            cell(g, "mean_similarity", ".3f"),
            cell(u, "mean_similarity", ".3f"),
            cell(g, "mean_seconds", ".2f"),
            cell(u, "mean_seconds", ".2f"),
        ]
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    if 10 in guided:
        match = n_to_match(summary, float(guided[10]["mean_similarity"]))
        top = max(unguided) if unguided else 0
        said = f"more than {top}" if match != match else f"about {match:.0f}"
        lines += ["", f"Unguided SMC needs {said} particles to match the guide at N = 10."]
    try:
        from ngpm_compiler.experiments.plots import plot_similarity_vs_n

        plot_similarity_vs_n(summary, [UNGUIDED, "guide"], out / "curve.png", "validation targets")
        lines += ["", "![similarity vs N](curve.png)"]
    except ImportError:
        lines += ["", 'No plot: matplotlib is missing (pip install -e ".[eval]").']
    return lines


def write_report(out: Path, state: dict[str, Any], stopped: str | None) -> Path:
    """Write out/report.md (and out/curve.png) from the run's state."""
    stages = state["stages"]
    rounds = [stages[k]["result"] for k in sorted(stages) if k.startswith("round_")]
    best = max(rounds, key=lambda x: (x["validation"], -x["round"])) if rounds else None
    tuned = (stages.get("tune") or {}).get("result")
    diag = (stages.get("diagnose") or {}).get("result") or {}
    lines = [
        f"# ngpmc learn: {state['key']['grammar']}",
        "",
        f"Wall time spent: {_min(state['spent'])}."
        + (f" The budget ran out during {stopped}." if stopped else ""),
        "",
        f"Guide: `guide.onnx`: round {best['round'] if best else '-'}"
        + (f", tuned ({tuned['setting']})" if tuned else ", untuned")
        + (f"; grammar: `{Path(diag['grammar']).name}` (in this folder)" if diag else ""),
        "",
        *(CIRCUIT_NOTE if state["key"].get("likelihood") == "circuit" else ()),
        "## Grammar",
        "",
        *(f"    {x}" for x in diag.get("lines", [])),
        "",
        "## Rounds",
        "",
        "Validation similarity: mean over the validation targets of the median similarity "
        "at N = 10, every round's guide with the default proposal settings (equal settings).",
        "",
        *rounds_table(rounds, best["round"] if best else None),
        "",
        "## Tuning",
        "",
        *(tuned["table"].splitlines() if tuned else [NOT_TUNED]),
        "",
        "## Similarity vs N (validation targets)",
        "",
        *curve_lines((stages.get("curve") or {}).get("result"), out),
        "",
        "## Budget plan",
        "",
        *plan_lines(state),
        "",
        "## Wall time per stage",
        "",
        "| stage | time |",
        "|---|---|",
        *(f"| {k} | {_min(v['seconds'])} |" for k, v in stages.items()),
        "",
        "## Notes",
        "",
        *(f"- {n}" for n in state.get("notes", [])),
        "- features all+context, 4 mixture components, early stopping (patience 4 epochs); "
        "traces whose best particle drew fewer than 10 primitives are kept as data",
    ]
    return atomic_write(out / "report.md", "\n".join(lines) + "\n")
