"""The figures README.md and docs/results/README.md quote, written from the files in
docs/results, so that every number has one source.

A generated block sits between a `<!-- begin NAME -->` line and an `<!-- end NAME -->` line;
this script rewrites the text between them and leaves the rest of each page alone.
Sources: demo.md (`ngpmc demo`), quick_tour.md (`benchmarks/quick_tour.py`), heldout.csv
(`ngpmc eval --stages heldout`), and the full evaluation's settings.json, shape_summary.csv,
speedup.csv, trainset.csv, circuit_runs.csv and chain_runs.csv (`ngpmc eval`), and
circuit_guide.md (`benchmarks/circuit.py`).

Usage: python scripts/headline.py            # rewrite the blocks
       python scripts/headline.py --check    # exit 1 and name the blocks that are stale
"""

from __future__ import annotations

import argparse
import csv
import json
import re
import sys
import textwrap
from collections.abc import Callable
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "docs" / "results"
SHIPPED, UNTUNED = "round6b_tuned", "round6b"  # heldout.csv's names of the bundled guide
GUIDED_N = 10


class SourceError(Exception):
    """A source file lacks what a block needs."""


def _csv(name: str) -> list[dict[str, str]]:
    with open(RESULTS / name, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def _find(pattern: str, text: str, source: str) -> re.Match[str]:
    m = re.search(pattern, text, re.M)
    if m is None:
        raise SourceError(f"{source}: no line matches {pattern!r}")
    return m


def _two(x: float | str) -> str:
    return f"{float(x):.2f}"


def _list(xs: list[str]) -> str:
    return ", ".join(xs[:-1]) + " and " + xs[-1] if len(xs) > 1 else xs[0]


# --- sources -------------------------------------------------------------------------------


def demo() -> dict[str, list[str]]:
    """demo.md: the mean row (guided, seconds, unguided, seconds) and each target's runs."""
    text = (RESULTS / "demo.md").read_text(encoding="utf-8")
    mean = _find(r"^\| \*\*mean\*\* \| (.*) \|$", text, "demo.md").group(1).split(" | ")
    runs = {
        m.group(1): m.group(2).split(", ")
        for m in re.finditer(r"^- (\w+): guided ([\d., -]+); unguided", text, re.M)
    }
    return {"mean": mean, **runs}


def tour() -> dict[str, str]:
    """quick_tour.md: seconds per command, the load, the grow table."""
    text = (RESULTS / "quick_tour.md").read_text(encoding="utf-8")
    src = "quick_tour.md"
    out = {"cores": _find(r"^Machine: (\d+) cores", text, src).group(1)}
    load = _find(r"load average ([\d.]+) at the start, ([\d.]+) at the end", text, src)
    out["load0"], out["load1"] = load.groups()
    learn = _find(r"^\| `ngpmc learn .* --budget (\w+)` \| ([\d.]+) \|$", text, src)
    out["budget"], out["learn"] = learn.groups()
    out["total"] = _find(r"^\| \*\*the tour, in all\*\* \| \*\*([\d.]+)\*\* \|$", text, src).group(
        1
    )
    for key, guide in (("tuned", r"out/learn/guide\.onnx"), ("prior", "none")):
        row = _find(rf"^\| `--guide {guide}` \| (.*) \|$", text, src).group(1).split(" | ")
        out[key + "_list"] = _list([_two(x) for x in row[:-2]])
        out[key + "_mean"] = _two(row[-2])
    return out


def heldout() -> dict[tuple[str, str, int], dict[str, str]]:
    """heldout.csv by (set, model, N)."""
    return {(r["dataset"], r["model"], int(r["n"])): r for r in _csv("heldout.csv")}


# --- README.md -----------------------------------------------------------------------------


def readme_demo() -> str:
    d = demo()
    text = (RESULTS / "demo.md").read_text(encoding="utf-8")
    m3 = re.search(r"^\| \*\*mean 3D\*\* \| +\| (.*) \|$", text, re.M)
    in3d = ""
    if m3 is not None:  # the 3D rows: guided, seconds, unguided, seconds
        g, gs, u, us = m3.group(1).split(" | ")
        n_u = _find(r"^\| 3D target \|.* unguided N=(\d+) \| seconds \|$", text, "demo.md")[1]
        in3d = (
            f"; in 3D, guided N = 10 averaged {_two(g)} in {_two(gs)} s a run and unguided "
            f"N = {n_u} {_two(u)} in {_two(us)} s"
        )
    return (
        f"Over the 4 targets and 3 seeds, guided runs averaged similarity {_two(d['mean'][0])}"
        f" and unguided ones {_two(d['mean'][2])}{in3d} (every run and its seconds: "
        "[docs/results/demo.md](docs/results/demo.md))."
    )


def readme_tour_time() -> str:
    t = tour()
    return (
        f"On the project's {t['cores']}-core test machine, shared with other jobs (load "
        f"average {t['load0']} to {t['load1']}), `ngpmc learn` took "
        f"{float(t['learn']) / 60:.1f} minutes of its {t['budget']} budget and the whole tour "
        f"{float(t['total']) / 60:.1f} minutes (`python benchmarks/quick_tour.py` runs it as "
        "written and times it: [docs/results/quick_tour.md](docs/results/quick_tour.md); "
        "the run's report: [docs/results/quick_tour_learn.md](docs/results/quick_tour_learn.md))."
    )


def readme_tour_grow() -> str:
    t, horse = tour(), [float(x) for x in demo()["horse"]]
    return (
        "With the demo's horse as `my_picture.png` (`runtime/ngpm_runtime/data/demo_horse.png`"
        " and its sidecar `demo_horse.txt`, copied), 10 particles and seeds 0, 1, 2, this "
        f"guide reached similarity {t['tuned_list']} (mean {t['tuned_mean']}) "
        f"where the prior reached {t['prior_list']} (mean {t['prior_mean']}); the bundled "
        f"vines guide reaches {_two(min(horse))} to {_two(max(horse))} on the same picture "
        f"([docs/results/demo.md](docs/results/demo.md))."
    )


def readme_guide() -> str:
    h = heldout()
    parts = []
    for name, what in (
        ("script", "script glyphs (URW Z003)"),
        ("silhouettes", "Openclipart silhouettes"),
    ):
        top = max(n for (ds, m, n) in h if ds == name and m == "unguided")
        g, u = h[(name, SHIPPED, GUIDED_N)], h[(name, "unguided", top)]
        side = "above" if float(g["mean_similarity"]) > float(u["mean_similarity"]) else "below"
        parts.append(
            f"on {g['targets']} held-out {what} it scores {_two(g['mean_similarity'])} "
            f"at N = {GUIDED_N}, {side} unguided SMC with {top} particles "
            f"({_two(u['mean_similarity'])})"
        )
    untuned = [
        _two(h[(ds, UNTUNED, GUIDED_N)]["mean_similarity"]) for ds in ("script", "silhouettes")
    ]
    text = "; ".join(parts)
    return (
        text[0].upper() + text[1:] + f". Untuned, the same networks score {untuned[0]} "
        f"and {untuned[1]} ([docs/results](docs/results/README.md#the-shipped-guide))."
    )


# --- docs/results/README.md ----------------------------------------------------------------


def results_heldout() -> str:
    h = heldout()
    sets = sorted({ds for ds, _, _ in h})
    ns = sorted({n for (_, m, n) in h if m == "unguided"})
    head = [
        "set",
        "targets",
        f"shipped guide, N = {GUIDED_N}",
        "untuned",
        *(f"unguided N = {n}" for n in ns),
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for ds in sets:
        cells = [
            h[(ds, SHIPPED, GUIDED_N)],
            h[(ds, UNTUNED, GUIDED_N)],
            *(h[(ds, "unguided", n)] for n in ns),
        ]
        sims = [f"{float(c['mean_similarity']):.3f}" for c in cells]
        sims[0] = f"**{sims[0]}**"
        lines.append(f"| {ds} | {cells[0]['targets']} | " + " | ".join(sims) + " |")
    return "\n".join(lines)


def _evaluation() -> dict:
    return {
        "settings": json.loads((RESULTS / "settings.json").read_text()),
        "summary": _csv("shape_summary.csv"),
        "speed": _csv("speedup.csv"),
    }


def results_eval_settings() -> str:
    from ngpm_compiler.experiments.report import settings_lines

    return "\n".join(settings_lines(_evaluation()["settings"]))


def results_eval_headline() -> str:
    from ngpm_compiler.experiments.report import headline

    e = _evaluation()
    return "\n".join(headline(e["summary"], e["speed"], int(e["settings"]["guided_n"])))


def results_eval_similarity() -> str:
    from ngpm_compiler.evaluation.runs import UNGUIDED
    from ngpm_compiler.experiments.config import SHAPE_MODELS
    from ngpm_compiler.experiments.report import similarity_table

    models = [UNGUIDED, *SHAPE_MODELS, "all_k1"]
    return similarity_table(_evaluation()["summary"], "all", models).rstrip()


def results_eval_trainset() -> str:
    from ngpm_compiler.experiments.report import trainset_md

    return trainset_md(_csv("trainset.csv")).rstrip()


def results_eval_circuits() -> str:
    from ngpm_compiler.experiments.report import circuit_md

    return circuit_md(_csv("circuit_runs.csv")).rstrip()


def results_circuit_guide() -> str:
    """circuit_guide.md (`python benchmarks/circuit.py --md ...`) as it is."""
    return (RESULTS / "circuit_guide.md").read_text(encoding="utf-8").rstrip()


def results_eval_chain() -> str:
    from ngpm_compiler.experiments.report import chain_md

    return chain_md(_csv("chain_runs.csv")).rstrip()


def _wrapped(make: Callable[[], str]) -> Callable[[], str]:
    """A prose block, wrapped as the README is (92 columns)."""
    return lambda: textwrap.fill(make(), 92, break_on_hyphens=False)


PAGES: dict[str, dict[str, Callable[[], str]]] = {
    "README.md": {
        "demo": _wrapped(readme_demo),
        "tour-time": _wrapped(readme_tour_time),
        "tour-grow": _wrapped(readme_tour_grow),
        "guide": _wrapped(readme_guide),
    },
    "docs/results/README.md": {
        "heldout": results_heldout,
        "eval-settings": results_eval_settings,
        "eval-headline": results_eval_headline,
        "eval-similarity": results_eval_similarity,
        "eval-trainset": results_eval_trainset,
        "eval-circuits": results_eval_circuits,
        "circuit-guide": results_circuit_guide,
        "eval-chain": results_eval_chain,
    },
}


def render(text: str, blocks: dict[str, Callable[[], str]], page: str) -> str:
    """`text` with each block's lines replaced by what its function writes now."""
    for name, make in blocks.items():
        pattern = re.compile(
            rf"(^<!-- begin {re.escape(name)} -->\n).*?(^<!-- end "
            rf"{re.escape(name)} -->$)",
            re.M | re.S,
        )
        if len(pattern.findall(text)) != 1:
            raise SourceError(f"{page}: needs one block {name!r}")
        text = pattern.sub(lambda m, make=make: m.group(1) + make() + "\n" + m.group(2), text)
    return text


def stale() -> dict[str, str]:
    """Pages whose blocks differ from their sources: page -> the text it should have."""
    out = {}
    for page, blocks in PAGES.items():
        text = (REPO / page).read_text(encoding="utf-8")
        new = render(text, blocks, page)
        if new != text:
            out[page] = new
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="only say which pages are stale")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(REPO))
    sys.path.insert(0, str(REPO / "runtime"))
    try:
        todo = stale()
    except (SourceError, OSError, KeyError, ValueError) as err:
        print(f"headline: error: {err}", file=sys.stderr)
        return 1
    from ngpm_runtime.files import atomic_write

    for page, text in todo.items():
        if args.check:
            print(f"{page}: figures out of date; run python scripts/headline.py", file=sys.stderr)
        else:
            atomic_write(REPO / page, text.encode("utf-8"))
            print(f"rewrote the figures of {page}")
    return 1 if args.check and todo else 0


if __name__ == "__main__":
    sys.exit(main())
