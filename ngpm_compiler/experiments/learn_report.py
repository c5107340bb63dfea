"""OUT/report.md of `ngpmc learn` (and OUT/curve.png): validation similarity per round,
wall time per stage, the budget plan and its reasons, the tuning table, similarity vs N
of the guide and of unguided SMC on the validation targets, and what each rerun with a
larger budget added. Written from learn.json's state alone, so a stopped run's report shows
what finished."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ngpm_runtime.files import atomic_write

from ngpm_compiler.evaluation.diagnose import reach_seen
from ngpm_compiler.evaluation.runs import UNGUIDED, n_to_match
from ngpm_compiler.experiments.learn_plan import FEATURES, OWN_TEACHER

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


def _numbered(stages: dict[str, Any], base: str) -> list[str]:
    """The finished stages `base`, `base_1`, `base_2`... in that order."""
    names = [k for k in stages if k == base or k.removeprefix(base + "_").isdigit()]
    return sorted(names, key=lambda k: int(k.removeprefix(base + "_") if k != base else 0))


def latest(stages: dict[str, Any], base: str) -> tuple[str, Any] | None:
    """(name, result) of the last finished stage `base` or `base_<k>` (a rerun's), or None."""
    names = _numbered(stages, base)
    return (names[-1], stages[names[-1]]["result"]) if names else None


def tuned_result(stages: dict[str, Any], best: int | None) -> dict[str, Any] | None:
    """The last finished tuning that tuned round `best` (the best round), or None."""
    for name in reversed(_numbered(stages, "tune")):
        res = stages[name]["result"]
        if res and res["round"] == best:
            return dict(res)
    return None


def renewing(stages: dict[str, Any]) -> list[str]:
    """The k of each extend_<k> after which tuning and the curve run again (tune_<k>,
    curve_<k>): it added rounds, or a tune grid where none had been tuned."""
    out = []
    for name in _numbered(stages, "extend"):
        e = stages[name]["result"]
        if e.get("renews", e["plan"]["rounds"] > e["after_round"]):
            out.append(name.removeprefix("extend_"))
    return out


def latest_plan(stages: dict[str, Any]) -> dict[str, Any] | None:
    """The plan the run follows: the one of the last stage that planned (plan, replan, an
    extension extend_<k> or an addition fill_<e>_<k>, in the order they ran)."""
    p = None
    for name, stage in stages.items():
        if name in ("plan", "replan"):
            p = stage["result"]
        elif name.startswith(("extend_", "fill_")):
            p = stage["result"]["plan"]
    return dict(p) if p is not None else None


def reach_lines(diag: dict[str, Any] | None, warn: bool = True) -> list[str]:
    """What unguided SMC reached on a few training targets (the `reach` stage); its warning
    in bold when `warn` (not when the run switched to envelopes: their line says why)."""
    if not diag:
        return []
    line = (
        f"unguided SMC, {diag['n']} particles, on {len(diag['targets'])} training targets: "
        f"similarity {diag['similarity']:.3f}; "
        f"{reach_seen(diag['drawn'], diag['covered'], diag['ink'], diag.get('dim', 2))}"
    )
    return ["", line, *(["", f"**{diag['warning']}**"] if diag["warning"] and warn else [])]


def _switched(stages: dict[str, Any]) -> bool:
    return bool(((stages.get("envelopes") or {}).get("result") or {}).get("switched"))


def targets_lines(stages: dict[str, Any]) -> list[str]:
    """Which targets the run trained and validated on, and why envelopes when it switched
    to them (the `envelopes` stage)."""
    switch = (stages.get("envelopes") or {}).get("result")
    t = (stages.get("targets") or {}).get("result")
    if switch is not None and switch["switched"]:
        t = switch["targets"]
    if not t or t["train"] == [""]:
        return []
    val = ", ".join(f"{k} (`{Path(v).name}`)" for k, v in t["validation"].items())
    train = ", ".join(f"`{Path(d).name}`" for d in t["train"])
    return [
        "",
        f"Targets: training {train}; validation {val}.",
        *(["", f"**{switch['line']}**"] if switch else []),
    ]


def rounds_table(rounds: list[dict[str, Any]], best: int | None) -> list[str]:
    lines = [
        "| round | teacher | traces trained on | validation NLL | validation similarity "
        "(N = 10) | traces | training | validation |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rounds:
        s = r["seconds"]
        sim = f"{r['validation']:.3f}"
        # a training stopped early to leave time for tuning and the curve (learn.train)
        cut = f" ({r['train_epochs']} epochs, stopped for time)" if r.get("train_stopped") else ""
        lines.append(
            f"| {r['round']}{' (best)' if r['round'] == best else ''} | {r['teacher']} | "
            f"{r['traces']} | {r['val_nll']} | {f'**{sim}**' if r['round'] == best else sim} | "
            f"{_min(s['traces'])} | {_min(s['train'])}{cut} | {_min(s['validation'])} |"
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


def _own_rounds(stages: dict[str, Any]) -> bool:
    """Whether the rounds recorded ground-truth traces (learn on envelope targets)."""
    return any(
        (v.get("result") or {}).get("teacher") == OWN_TEACHER
        for k, v in stages.items()
        if k.startswith("round_")
    )


def plan_lines(state: dict[str, Any]) -> list[str]:
    stages = state["stages"]
    p = latest_plan(stages)
    if p is None:
        return ["No plan was made (the run stopped before)."]
    c = state.get("costs", {})
    when = (
        f"extended for a budget of {_min(p['total'])}, {_min(p['budget'])} of it left"
        if latest(stages, "extend")
        else f"planned for {_min(p['budget'])} (what was left after the diagnosis, the "
        "targets and the measurement)"
    )
    lines = [
        f"The plan as {when}. {measured(c)}",
        "",
        f"- round 0: {p['traces']} traces from unguided SMC with {p['unguided_particles']} "
        f"particles; then up to {p['rounds']} guided round(s) of {p['guided_traces']} traces with "
        f"{p['guided_particles']} particles, each trained on every round's traces"
        + "".join(
            f"; round {p['rounds'] + i + 1}: {n} traces with {pg} particles"
            for i, (n, pg) in enumerate(p.get("more", ()))
        )
        + (
            " (on envelopes each round recorded its own samples' ground-truth traces in "
            "place of these: the rounds table)"
            if _own_rounds(stages)
            else ""
        ),
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


def extension_lines(stages: dict[str, Any]) -> list[str]:
    """What each rerun with a larger budget planned and added (rounds, traces, the best
    validation similarity before and after)."""
    rounds = [stages[k]["result"] for k in sorted(stages) if k.startswith("round_")]
    names = [n for n in _numbered(stages, "extend") if n != "extend"]
    if not names:
        return ["None: the run was planned once."]
    lines = []
    for name in names:
        e = stages[name]["result"]
        p, after = e["plan"], e["after_round"]
        last = max(after, p["rounds"] + len(p.get("more", ())))
        old = [r for r in rounds if r["round"] <= after]
        new = [r for r in rounds if after < r["round"] <= last]
        head = (
            f"- `{name}`: the budget grew from {_min(e['budget_before'])} to "
            f"{_min(p['total'])} after {_min(e['spent'])} spent; {p['reasons'][-1]}."
        )
        if not new:
            retune = " (tuning and the curve run again)" if e.get("renews") else ""
            lines.append(f"{head} Added no finished round{retune}.")
            continue
        before = max(r["validation"] for r in old)
        best = max(new + old, key=lambda r: (r["validation"], -r["round"]))
        added = new[-1]["traces"] - old[-1]["traces"]
        span = f"{new[0]['round']}" + (f" to {new[-1]['round']}" if len(new) > 1 else "")
        lines.append(
            f"{head} Added round(s) {span} ({added} traces): best validation similarity "
            f"{before:.3f} before, {best['validation']:.3f} after (round {best['round']})."
        )
    return lines


def write_report(out: Path, state: dict[str, Any], stopped: str | None) -> Path:
    """Write out/report.md (and out/curve.png) from the run's state."""
    stages = state["stages"]
    rounds = [stages[k]["result"] for k in sorted(stages) if k.startswith("round_")]
    best = max(rounds, key=lambda x: (x["validation"], -x["round"])) if rounds else None
    tuned = tuned_result(stages, best["round"] if best else None)
    diag = (stages.get("diagnose") or {}).get("result") or {}
    curve = latest(stages, "curve")
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
        *reach_lines((stages.get("reach") or {}).get("result"), not _switched(stages)),
        *targets_lines(stages),
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
        *curve_lines(curve[1] if curve else None, out),
        *_stale_curve(curve[0] if curve else None, stages),
        "",
        "## Budget plan",
        "",
        *plan_lines(state),
        "",
        "## Reruns with a larger budget",
        "",
        *extension_lines(stages),
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
        f"- features {_features(stages)}, hidden units {_width(stages)} per input, 4 mixture "
        f"components, early stopping (patience "
        f"{_patience(stages)} epochs){_warm(stages)}; traces whose best particle drew fewer "
        "than 10 primitives are kept as data",
    ]
    return atomic_write(out / "report.md", "\n".join(lines) + "\n")


def _of_rounds(stages: dict[str, Any], key: str) -> str:
    """What the rounds' results record under `key`, each value once ("" if none does)."""
    seen = [
        str(v["result"][key])
        for k, v in sorted(stages.items())
        if k.startswith("round_") and (v.get("result") or {}).get(key) is not None
    ]
    return ", ".join(dict.fromkeys(seen))


def _features(stages: dict[str, Any]) -> str:
    """The feature set the rounds trained with (a round from before they recorded it: the
    dimension's default, a 3D grammar's rows have no context)."""
    dim = ((stages.get("diagnose") or {}).get("result") or {}).get("dim", 2)
    return _of_rounds(stages, "features") or FEATURES[dim]


def _patience(stages: dict[str, Any]) -> str:
    """The rounds' early-stopping patience (4 before they recorded it)."""
    return _of_rounds(stages, "patience") or "4"


def _width(stages: dict[str, Any]) -> str:
    """The site networks' hidden units per input (0.5 before the rounds recorded it)."""
    return _of_rounds(stages, "hidden_per_input") or "0.5"


def _warm(stages: dict[str, Any]) -> str:
    """', each round's training warm-started from the last round's' when rounds were."""
    warm = [
        v["result"]["round"]
        for k, v in sorted(stages.items())
        if k.startswith("round_") and (v.get("result") or {}).get("warm_start")
    ]
    return (
        f", rounds {', '.join(map(str, warm))} warm-started from the round before" if warm else ""
    )


def _stale_curve(name: str | None, stages: dict[str, Any]) -> list[str]:
    """A note when the curve shown was measured before the last rerun renewed the guide."""
    ext = renewing(stages)
    if name is None or not ext or name == f"curve_{ext[-1]}":
        return []
    return ["", f"(Measured by `{name}`, for the guide before the last rerun's changes.)"]
