"""`ngpmc learn` on several grammars, each guide then scored on held-out targets: the table
of issue #23 (does the recipe hold beyond vines?).

    python benchmarks/learn_grammars.py --budget 45m \
        --grammars vines,ivy,bush,stochastic_plant,grass,lily,canopy -o work/learn_grammars

For each grammar (`grammars/NAME.lsys`, `ivy` = the README's quick-tour grammar, or a path
to an .lsys file) it runs `ngpmc learn GRAMMAR -o OUT/NAME/learn --budget B` (its own
process; a finished run is a quick no-op and an interrupted one resumes), then scores
OUT/NAME/learn/guide.onnx on held-out targets that neither learn's training nor its
validation uses (`varied` strokes and procedural `shapes` of other seeds, built once in
OUT/heldout; for a grammar whose learn trained on envelopes of its own samples, because
unguided SMC reaches the generic targets too poorly, envelopes of seeds 2001 and 2002
instead, built in OUT/NAME/heldout_envelopes): guided SMC at N = 10 against unguided SMC
at each N of `--ns`, every run of a grammar shuffled together (interleaved, so a changing
load hits both alike) and cached in OUT/NAME/heldout (evaluation/heldout.py). A grammar
whose OUT/NAME/result.json was written under the same settings is skipped, so the command
resumes where it stopped.

Per grammar: learn's wall time, its rounds and best validation similarity, the mean over
both held-out sets of the per-target median similarity at each N, the unguided N that
matches the guide at N = 10 (log-interpolated; "> N" when no N of the ladder does), and
the time ratio at equal similarity (unguided seconds to reach the guide's N = 10
similarity over the guide's seconds; "> x" when unguided never reaches it), and the
held-out targets it was scored on. Written to
OUT/learn_grammars.csv and OUT/learn_grammars.md, and into the `<!-- begin learn-grammars
-->` block of `--page` (default docs/results/learn_grammars.md, made when missing; its
source file learn_grammars.csv is copied beside it). The machine may be shared: the load
average at the start and end is written with the table.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from ngpm_runtime.files import atomic_write

from ngpm_compiler.evaluation.runs import UNGUIDED, n_to_match, speedups, summarize

REPO = Path(__file__).resolve().parents[1]
HELDOUT = {"varied": ("varied", 2001), "shapes": ("shapes", 2002)}  # name: (dataset, seed)
# a grammar learn trained on envelopes of (experiments/learn.py) is scored on these
HELDOUT_ENVELOPES = {"envelopes_2001": ("envelopes", 2001), "envelopes_2002": ("envelopes", 2002)}
GUIDED_N = 10
BLOCK = "learn-grammars"
CSV_FIELDS = ("grammar", "model", "n", "targets", "mean_similarity", "mean_seconds")


def grammar_file(name: str, out: Path) -> Path:
    """The .lsys file of `name`: a path, `ivy` (the README's tour grammar, written into
    OUT/ivy_source) or grammars/NAME.lsys."""
    if name.endswith(".lsys"):
        return Path(name).resolve()
    if name == "ivy" and not (REPO / "grammars" / "ivy.lsys").is_file():
        from ngpm_compiler.cli import tour

        readme = (REPO / "README.md").read_text(encoding="utf-8")
        return out / "ivy_source" / tour.prepare(readme, out / "ivy_source")
    path = REPO / "grammars" / f"{name}.lsys"
    if not path.is_file():
        raise SystemExit(f"{name}: no grammars/{name}.lsys (give a path to an .lsys file)")
    return path


def heldout_sets(out: Path, count: int) -> dict[str, str]:
    """The held-out target sets (built once; other seeds than learn's sets)."""
    from ngpm_compiler.datasets.build import build_dataset

    sets = {}
    for name, (dataset, seed) in HELDOUT.items():
        d = out / "heldout" / f"{name}_{count}"
        build_dataset(dataset, d, count=count, seed=seed)
        sets[name] = str(d)
    return sets


def learned_targets(out: Path) -> str:
    """What learn trained on: "envelopes" of the grammar (--targets envelopes, or switched
    to after its reach check) or "generic" targets."""
    state = json.loads((out / "learn" / "learn.json").read_text(encoding="utf-8"))
    stages = state["stages"]
    switch = (stages.get("envelopes") or {}).get("result") or {}
    kind = stages["targets"]["result"].get("kind")
    return "envelopes" if switch.get("switched") or kind == "envelopes" else "generic"


def envelope_sets(grammar: Path, out: Path, count: int) -> dict[str, str]:
    """Held-out envelopes of `grammar` (learn's copy, with its viewport), in OUT/NAME."""
    from ngpm_compiler.datasets.build import build_dataset

    sets = {}
    for name, (dataset, seed) in HELDOUT_ENVELOPES.items():
        d = out / "heldout_envelopes" / f"{name}_{count}"
        build_dataset(dataset, d, count=count, seed=seed, grammar=grammar)
        sets[name] = str(d)
    return sets


def run_learn(grammar: Path, out: Path, args: argparse.Namespace) -> float:
    """`ngpmc learn` in its own process (output in OUT/learn.log); its wall seconds."""
    out.mkdir(parents=True, exist_ok=True)
    argv = [sys.executable, "-m", "ngpm_compiler.cli", "learn", str(grammar), "-o"]
    argv += [str(out / "learn"), "--budget", args.budget, "--workers", str(args.workers)]
    argv += ["--seed", str(args.seed)] + (["--tune-teachers"] if args.tune_teachers else [])
    t0 = time.perf_counter()
    with open(out / "learn.log", "ab") as log:
        code = subprocess.call(argv, stdout=log, stderr=subprocess.STDOUT)
    if code != 0:
        tail = (out / "learn.log").read_text(encoding="utf-8", errors="replace")[-600:]
        raise SystemExit(f"ngpmc learn {grammar.name} failed ({code}):\n{tail}")
    return time.perf_counter() - t0


def learn_facts(out: Path) -> dict[str, Any]:
    """From learn.json: wall time spent, rounds, the best validation similarity; from the
    last call's output (learn.log): whether the budget stopped it."""
    state = json.loads((out / "learn" / "learn.json").read_text(encoding="utf-8"))
    rounds = [v["result"] for k, v in state["stages"].items() if k.startswith("round_")]
    best = max(rounds, key=lambda r: r["validation"])
    log = (out / "learn.log").read_text(encoding="utf-8", errors="replace")
    ends = re.findall(r"^(ngpmc learn: the budget ran out|\S+guide\.onnx: done in)", log, re.M)
    return {
        "learn_minutes": round(state["spent"] / 60, 2),
        "rounds": len(rounds),
        "best_round": best["round"],
        "validation": best["validation"],
        "stopped": bool(ends) and ends[-1].startswith("ngpmc learn: the budget"),
    }


def figures(summary: list[dict[str, Any]]) -> dict[str, Any]:
    """Guided N = 10 against the unguided ladder: similarities, crossing N, time ratio."""
    guided = next(r for r in summary if r["model"] == "guide" and int(r["n"]) == GUIDED_N)
    sim = float(guided["mean_similarity"])
    unguided = sorted((r for r in summary if r["model"] == UNGUIDED), key=lambda r: int(r["n"]))
    match = n_to_match(summary, sim)
    speed = speedups(summary, ["guide"], [sim])[0]
    return {
        "guided": sim,
        "guided_seconds": float(guided["mean_seconds"]),
        "unguided": {int(r["n"]): float(r["mean_similarity"]) for r in unguided},
        "match_n": None if math.isnan(match) else round(match, 1),
        "ratio": None if speed["speedup"] == "" else float(speed["speedup"]),
        "ratio_bound": speed["bound"],
    }


def evaluate(name: str, grammar: Path, out: Path, sets: dict[str, str], args: Any) -> list:
    """The guide and unguided SMC on the held-out sets (runs cached); summary over both."""
    from ngpm_compiler.evaluation.heldout import run_heldout

    res = run_heldout(
        out / "heldout",
        str(grammar),
        sets,
        {"guide": str(out / "learn" / "guide.onnx")},
        k=args.targets,
        repeats=args.repeats,
        guided_n=GUIDED_N,
        unguided_ns=tuple(args.ns),
        workers=args.workers,
        seed=args.seed + 7,
        log=lambda m: print(f"{name}: {m}", flush=True),
    )
    return summarize(res["rows"], "all")


def settings(args: argparse.Namespace) -> dict[str, Any]:
    keys = ("budget", "targets", "repeats", "ns", "workers", "seed")
    out = {k: getattr(args, k) for k in keys}
    if args.tune_teachers:  # only when on: results recorded before the option stay valid
        out["tune_teachers"] = True
    return out


def one_grammar(name: str, out: Path, sets: dict[str, str], args: Any) -> dict[str, Any]:
    """Learn and evaluate one grammar, or its recorded result under the same settings."""
    path = out / name / "result.json"
    if path.is_file():
        old = json.loads(path.read_text(encoding="utf-8"))
        if old.get("settings") == settings(args):
            print(f"{name}: done before ({path})", flush=True)
            return dict(old)
    grammar = grammar_file(name, out)
    print(f"{name}: ngpmc learn {grammar} --budget {args.budget}", flush=True)
    wall = run_learn(grammar, out / name, args)
    learned = sorted((out / name / "learn").glob("*.lsys"))  # with a proposed viewport
    grammar = learned[0] if learned else grammar
    kind = learned_targets(out / name)
    if kind == "envelopes":
        sets = envelope_sets(grammar, out / name, args.targets)
    summary = evaluate(name, grammar, out / name, sets, args)
    result = {
        "grammar": name,
        "heldout": "envelopes" if kind == "envelopes" else ", ".join(HELDOUT),
        "settings": settings(args),
        "learn_call_seconds": round(wall, 1),
        **learn_facts(out / name),
        **figures(summary),
        "summary": summary,
    }
    atomic_write(path, json.dumps(result, indent=1) + "\n")
    return result


def table(results: list[dict[str, Any]], ns: list[int]) -> list[str]:
    """The Markdown table: one row per grammar."""
    head = "| grammar | learn (min) | rounds | guided N = 10 | " + " | ".join(
        f"unguided N = {n}" for n in ns
    )
    lines = [
        head + " | unguided N to match | time ratio at equal similarity | held-out targets |",
        "|---|---|---|---|" + "---|" * len(ns) + "---|---|---|",
    ]
    for r in results:
        u = {int(k): v for k, v in r["unguided"].items()}
        match = f"{r['match_n']:.0f}" if r["match_n"] is not None else f"> {max(ns)}"
        if u and r["guided"] <= u[min(u)]:  # no better than the smallest unguided N
            match = f"<= {min(u)}"
        ratio = "" if r["ratio"] is None else f"{r['ratio_bound']}{r['ratio']:.1f}x".strip()
        stop = " (budget ran out)" if r["stopped"] else ""
        cells = [f"{u[n]:.3f}" if n in u else "" for n in ns]
        lines.append(
            f"| {r['grammar']} | {r['learn_minutes']:.1f}{stop} | {r['rounds']} | "
            f"**{r['guided']:.3f}** | " + " | ".join(cells) + f" | {match} | {ratio} | "
            f"{r.get('heldout', ', '.join(HELDOUT))} |"
        )
    return lines


def block(results: list[dict[str, Any]], args: Any, load: tuple[float, float]) -> str:
    """The text of the page's learn-grammars block."""
    sets = ", ".join(f"`{d}` seed {s}" for d, s in HELDOUT.values())
    seeds = " and ".join(str(seed) for _, seed in HELDOUT_ENVELOPES.values())
    sets += f"; envelopes of its own samples, seeds {seeds}, for a grammar learn trained on them"
    return "\n".join(
        [
            f"`ngpmc learn --budget {args.budget}` per grammar, then on held-out targets "
            f"({sets}; {args.targets} per set, {args.repeats} run(s) per target and N; "
            "mean over targets of the median similarity), guided N = 10 against unguided "
            f"SMC; {os.cpu_count()} cores, load average {load[0]:.1f} at the start and "
            f"{load[1]:.1f} at the end (`python benchmarks/learn_grammars.py --budget "
            f"{args.budget} --grammars {','.join(args.grammars)}"
            f"{' --tune-teachers' if args.tune_teachers else ''}`).",
            "",
            *table(results, list(args.ns)),
        ]
    )


def write_page(page: Path, text: str) -> None:
    """Replace the page's learn-grammars block with `text` (the page is made if missing)."""
    begin, end = f"<!-- begin {BLOCK} -->", f"<!-- end {BLOCK} -->"
    old = page.read_text(encoding="utf-8") if page.is_file() else ""
    if begin not in old:
        old = (
            f"{old}# ngpmc learn on several grammars\n\nMade by `python "
            f"benchmarks/learn_grammars.py` (its docstring says how).\n\n{begin}\n{end}\n"
        )
    pattern = re.compile(rf"(^{re.escape(begin)}\n).*?(^{re.escape(end)}$)", re.M | re.S)
    new = pattern.sub(lambda m: m.group(1) + text + "\n" + m.group(2), old, count=1)
    atomic_write(page, new.encode("utf-8"))


def write_csv(path: Path, results: list[dict[str, Any]]) -> None:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=CSV_FIELDS, lineterminator="\n", extrasaction="ignore")
    w.writeheader()
    for r in results:
        for row in r["summary"]:
            w.writerow({**row, "grammar": r["grammar"]})
    atomic_write(path, buf.getvalue().encode("utf-8"))


def parse(argv: list[str] | None) -> argparse.Namespace:
    doc = __doc__ or ""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--budget", default="45m", help="ngpmc learn's --budget (45m)")
    ap.add_argument("--grammars", default="vines,ivy,bush,stochastic_plant,grass,lily,canopy")
    ap.add_argument("-o", "--out", default="work/learn_grammars", help="work folder")
    ap.add_argument("--targets", type=int, default=12, help="held-out targets per set (12)")
    ap.add_argument("--repeats", type=int, default=2, help="runs per target and N (2)")
    ap.add_argument("--ns", default="10,30,100,300,1000", help="unguided N (10,...,1000)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--tune-teachers", action="store_true", help="pass --tune-teachers to ngpmc learn"
    )
    ap.add_argument("--page", default=str(REPO / "docs" / "results" / "learn_grammars.md"))
    args = ap.parse_args(argv)
    args.grammars = [g.strip() for g in args.grammars.split(",") if g.strip()]
    args.ns = sorted({int(n) for n in args.ns.split(",")})
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    load0 = os.getloadavg()[0]
    sets = heldout_sets(out, args.targets)
    results = [one_grammar(name, out, sets, args) for name in args.grammars]
    text = block(results, args, (load0, os.getloadavg()[0]))
    write_csv(out / "learn_grammars.csv", results)
    atomic_write(out / "learn_grammars.md", text + "\n")
    page = Path(args.page)
    write_page(page, text)
    write_csv(page.with_suffix(".csv"), results)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
