"""Markdown from the evaluation's CSV files: README.md (headline figures, plots) and
report.md (every table and the settings). Reads only files in the results directory, so
it can be rerun alone (`ngpmc eval ... --stages report`). A hand-written `notes.md` in the
results directory is copied into README.md under "Discussion"."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from ngpm_runtime.files import atomic_write

from ngpm_compiler.evaluation.runs import UNGUIDED, curve, read_csv, time_to_reach
from ngpm_compiler.experiments.config import SHAPE_MODELS
from ngpm_compiler.experiments.extra import chain_table, circuit_table
from ngpm_compiler.experiments.plots import label

FIGURES = [
    ("fig4a_similarity.png", "Similarity vs particles, five models (paper Fig. 4a)"),
    ("fig4b_time.png", "Time to reach a similarity, and speedup over unguided (paper Fig. 4b)"),
    ("fig5a_mixture.png", "Mixture components K = 4 vs K = 1 (paper Fig. 5a)"),
    ("fig5b_trainset.png", "Similarity vs number of training traces (paper Fig. 5b)"),
    ("grid_glyphs.png", "Held-out glyphs (paper Fig. 2 / 6 layout)"),
    ("grid_silhouettes.png", "Held-out silhouettes (paper Fig. 2 / 6 layout)"),
    ("circuit.png", "Circuits: vines under the circuit likelihood (paper Fig. 6, right)"),
    ("chain.png", "Chain model (paper Fig. 1)"),
]


def _read(out: Path, name: str) -> list[dict[str, Any]]:
    p = out / name
    return read_csv(p) if p.is_file() else []


def _f(x: Any, nd: int = 3) -> str:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return "-"
    return "-" if math.isnan(v) else f"{v:.{nd}f}"


def _table(header: list[str], rows: list[list[Any]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def similarity_table(summary: list[dict[str, Any]], dataset: str, models: list[str]) -> str:
    sub = [r for r in summary if r["dataset"] == dataset]
    ns = sorted({int(r["n"]) for r in sub})
    rows = []
    for m in models:
        cells = []
        for n in ns:
            r = next((x for x in sub if x["model"] == m and int(x["n"]) == n), None)
            cells.append(_f(r["mean_similarity"]) if r else "")
        if any(cells):
            rows.append([label(m), *cells])
    return _table(["model \\ N", *map(str, ns)], rows)


def ci_table(summary: list[dict[str, Any]], dataset: str, models: list[str]) -> str:
    sub = [r for r in summary if r["dataset"] == dataset and r["model"] in models]
    rows = [
        [
            label(r["model"]),
            r["n"],
            r["targets"],
            _f(r["mean_similarity"]),
            f"[{_f(r['ci_low'])}, {_f(r['ci_high'])}]",
            _f(r["mean_seconds"]),
        ]
        for r in sorted(sub, key=lambda r: (models.index(r["model"]), int(r["n"])))
    ]
    return _table(["model", "N", "targets", "similarity", "95% CI", "mean s"], rows)


def match_table(summary: list[dict[str, Any]], dataset: str, models: list[str]) -> str:
    sub = [r for r in summary if r["dataset"] == dataset]
    ns_u, s_u, _ = curve(sub, UNGUIDED)
    rows = []
    for m in models:
        for r in sorted((x for x in sub if x["model"] == m), key=lambda x: int(x["n"])):
            need = time_to_reach(s_u, ns_u.astype(float), float(r["mean_similarity"]))
            txt = f"> {int(ns_u.max())}" if math.isnan(need) else f"{need:.0f}"
            ratio = "" if math.isnan(need) else f"{need / int(r['n']):.1f}"
            rows.append([label(m), r["n"], _f(r["mean_similarity"]), txt, ratio])
    return _table(["model", "N", "similarity", "unguided N to match", "particle ratio"], rows)


def headline(
    summary: list[dict[str, Any]], speed: list[dict[str, Any]], guided_n: int
) -> list[str]:
    """Sentences with the task's target figures."""
    lines = []
    for ds in ("glyphs", "silhouettes", "all"):
        sub = [r for r in summary if r["dataset"] == ds]
        g = next((r for r in sub if r["model"] == "all" and int(r["n"]) == guided_n), None)
        if not g:
            continue
        ns, s, _ = curve(sub, UNGUIDED)
        if not len(ns):
            continue
        sim = float(g["mean_similarity"])
        n_match = time_to_reach(s, ns.astype(float), sim)
        u200 = next((r for r in sub if r["model"] == UNGUIDED and int(r["n"]) == 200), None)
        txt = (
            f"- **{ds}**: guided (all features) N = {guided_n}: similarity {_f(sim)} "
            f"in {_f(g['mean_seconds'], 2)} s"
        )
        if u200:
            txt += (
                f"; unguided N = 200: {_f(u200['mean_similarity'])} in "
                f"{_f(u200['mean_seconds'], 2)} s"
            )
        if math.isnan(n_match):
            need = f"more than {int(ns.max())}"
        elif n_match <= ns.min() and sim <= s[0]:
            need = f"at most {int(ns.min())}"
        else:
            need = f"about {n_match:.0f}"
        txt += f"; unguided needs {need} particles to match it."
        lines.append(txt)
    allsp = [r for r in speed if r["model"] == "all" and r["speedup"] not in ("", None)]
    if allsp:
        best = max(allsp, key=lambda r: float(r["speedup"]))
        lines.append(
            f"- **speedup** (all features vs unguided, equal similarity): up to "
            f"{r_bound(best)}{float(best['speedup']):.1f}x (at similarity "
            f"{best['threshold']}); by threshold: "
            + ", ".join(f"{r['threshold']}: {r_bound(r)}{float(r['speedup']):.1f}x" for r in allsp)
            + "."
        )
    order = []
    for m in [UNGUIDED, *SHAPE_MODELS]:
        r = next(
            (
                x
                for x in summary
                if x["dataset"] == "all" and x["model"] == m and int(x["n"]) == guided_n
            ),
            None,
        )
        if r:
            order.append(f"{label(m)} {_f(r['mean_similarity'])}")
    if order:
        lines.append(
            f"- **ablation at N = {guided_n}** (all test targets): " + "; ".join(order) + "."
        )
    return lines


def r_bound(r: dict[str, Any]) -> str:
    return ">" if r.get("bound") == ">" else ""


def write_reports(out_dir: str | Path, command: str = "") -> tuple[Path, Path]:
    """Write the results folder's report and README from its CSVs and settings.

    Long because it is the report's text, section by section, in reading order."""
    out = Path(out_dir)
    settings = (
        json.loads((out / "settings.json").read_text()) if (out / "settings.json").is_file() else {}
    )
    summary = _read(out, "shape_summary.csv")
    speed = _read(out, "speedup.csv")
    models = _read(out, "models.csv")
    trainset = _read(out, "trainset.csv")
    grids = _read(out, "grids.csv")
    circuit = _read(out, "circuit_runs.csv")
    chain = _read(out, "chain_runs.csv")
    guided_n = int(settings.get("guided_n", 10))
    main = [UNGUIDED, *SHAPE_MODELS]

    rd = ["# Results", ""]
    commands = list(dict.fromkeys([*settings.get("commands", {}).values(), command]))
    commands = [c for c in commands if c]
    if commands:
        rd += ["Produced by (from the repository root):", "", "```bash", *commands, "```", ""]
    rd += settings_lines(settings) + [""]
    if summary:
        rd += ["## Headline figures", ""] + headline(summary, speed, guided_n) + [""]
        rd += [
            "## Shape matching: similarity by N (mean of per-target medians, all test targets)",
            "",
            similarity_table(summary, "all", main + ["all_k1"]),
        ]
        for ds in ("glyphs", "silhouettes"):
            if any(r["dataset"] == ds for r in summary):
                rd += [f"Held-out {ds} only:", "", similarity_table(summary, ds, main)]
    if trainset:
        rd += [
            f"## Training-set size (similarity at N = {trainset[0]['n']})",
            "",
            trainset_md(trainset),
        ]
    if circuit:
        rd += ["## Circuits", "", circuit_md(circuit)]
    if chain:
        rd += ["## Chain", "", chain_md(chain)]
    rd += ["## Figures", ""]
    for fname, title in FIGURES:
        if (out / fname).is_file():
            rd += [f"### {title}", "", f"![{title}]({fname})", ""]
    notes = out / "notes.md"
    if notes.is_file():
        rd += ["## Discussion", "", notes.read_text(encoding="utf-8").strip(), ""]
    rd += heldout_section(out)
    rd += [
        "Every number: [report.md](report.md); raw runs: `shape_runs.csv`, "
        "`circuit_runs.csv`, `chain_runs.csv`.",
        "",
    ]
    readme = atomic_write(out / "README.md", "\n".join(rd).encode("utf-8"))

    rp = ["# Evaluation report", ""] + settings_lines(settings) + [""]
    if models:
        rp += [
            "## Guides",
            "",
            _table(
                [
                    "model",
                    "features",
                    "K",
                    "traces",
                    "held out",
                    "best epoch",
                    "val NLL/trace",
                    "train s",
                ],
                [
                    [
                        r["model"],
                        r["features"],
                        r["K"],
                        r["traces"],
                        r["val_traces"],
                        r["best_epoch"],
                        r["val_nll"],
                        r["train_seconds"],
                    ]
                    for r in models
                ],
            ),
        ]
    for ds in ("all", "glyphs", "silhouettes"):
        if any(r["dataset"] == ds for r in summary):
            rp += [
                f"## Similarity with 95% CI: {ds}",
                "",
                ci_table(
                    summary,
                    ds,
                    main
                    + ["all_k1"]
                    + sorted({r["model"] for r in summary if r["model"].startswith("all_n")}),
                ),
            ]
    if summary:
        rp += [
            "## Unguided particles needed to match each guided run (all test targets)",
            "",
            "N of unguided SMC (log-interpolated) whose mean similarity equals the model's "
            "at its N; '>' where unguided never gets there.",
            "",
            match_table(summary, "all", list(SHAPE_MODELS) + ["all_k1"]),
        ]
    if speed:
        rp += [
            "## Time to reach a similarity (all test targets)",
            "",
            _table(
                ["model", "similarity", "seconds", "unguided seconds", "speedup"],
                [
                    [
                        label(r["model"]),
                        r["threshold"],
                        _f(r["seconds"]),
                        _f(r["baseline_seconds"]),
                        (r_bound(r) + _f(r["speedup"], 1)) if r["speedup"] else "-",
                    ]
                    for r in speed
                ],
            ),
        ]
    if grids:
        rp += [
            "## Result grids",
            "",
            _table(
                ["set", "target", "run", "N", "seconds", "similarity"],
                [
                    [r["dataset"], r["target"], r["kind"], r["n"], r["seconds"], r["similarity"]]
                    for r in grids
                ],
            ),
        ]
    if circuit:
        rp += ["## Circuits", "", circuit_md(circuit)]
    if chain:
        rp += ["## Chain", "", chain_md(chain)]
    rp += ["## Settings", "", "```json", json.dumps(settings, indent=1), "```", ""]
    report = atomic_write(out / "report.md", "\n".join(rp).encode("utf-8"))
    return readme, report


def heldout_section(out: Path) -> list[str]:
    """ "Expert iteration and held-out sets": the hand-written `heldout_notes.md` (commands,
    per-round table, discussion) and the table `ngpmc eval --stages heldout` wrote."""
    notes, table = out / "heldout_notes.md", out / "heldout.md"
    if not table.is_file():
        return []
    lines = ["## Expert iteration and held-out sets", ""]
    if notes.is_file():
        lines += [notes.read_text(encoding="utf-8").strip(), ""]
    lines += [
        "### Held-out table (from `heldout.md`; mean over targets of the median "
        "similarity over runs)",
        "",
        table.read_text(encoding="utf-8").strip(),
        "",
    ]
    return lines


def settings_lines(s: dict[str, Any]) -> list[str]:
    if not s:
        return []
    tests = ", ".join(f"{k}: {v}" for k, v in s.get("test_targets", {}).items())
    return [
        f"Settings: test targets ({tests}); N = {', '.join(map(str, s.get('ns', [])))} "
        f"(unguided also {', '.join(map(str, s.get('unguided_extra_ns', [])))}); "
        f"{s.get('repeats')} repeats per target and N; training traces: "
        f"{s.get('kept_traces')} ({s.get('traces')}); workers: {s.get('workers')}; "
        f"wall time of the whole evaluation: {s.get('wall_minutes', '?')} min; "
        f"machine: {s.get('machine', '?')}."
    ]


def trainset_md(rows: list[dict[str, Any]]) -> str:
    return _table(
        ["traces", "model", "similarity", "95% CI"],
        [
            [
                r["traces"],
                r["model"],
                _f(r["mean_similarity"]),
                f"[{_f(r['ci_low'])}, {_f(r['ci_high'])}]",
            ]
            for r in rows
        ],
    )


def circuit_md(rows: list[dict[str, Any]]) -> str:
    t = circuit_table(rows)
    return _table(
        ["run", "N (mean)", "score (eq. 2 argument)", "95% CI", "seconds"],
        [
            [
                r["kind"],
                f"{r['n']:.0f}",
                _f(r["score"]),
                f"[{_f(r['ci_low'])}, {_f(r['ci_high'])}]",
                _f(r["seconds"], 2),
            ]
            for r in t
        ],
    )


def chain_md(rows: list[dict[str, Any]]) -> str:
    t = chain_table(rows)
    return _table(
        ["model", "N", "similarity", "95% CI", "seconds"],
        [
            [
                r["model"],
                r["n"],
                _f(r["similarity"]),
                f"[{_f(r['ci_low'])}, {_f(r['ci_high'])}]",
                _f(r["seconds"], 3),
            ]
            for r in t
        ],
    )
