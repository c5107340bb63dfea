"""Does `turtle arguments: lazy` help SMC? The same grammar, eager and lazy (the same
distribution of samples), unguided SMC at several N on the same targets, interleaved.

    python experiments/lazy_arguments.py GRAMMAR TARGET_DIR[,DIR...] [--ns 10,100,1000]
        [--runs 2] [--seed 0]
    python experiments/lazy_arguments.py GRAMMAR envelopes [--work work/lazy_arguments]

`envelopes` builds the targets first: 12 envelopes of the grammar's eager samples for each
of the seeds 2001 and 2002 (benchmarks/learn_grammars.py's held-out envelopes of it, as
they were before the grammar said lazy), in --work.

Prints, per N and per setting, the mean over targets of the median similarity of `--runs`
runs (seeds seed + run, the same for both settings) and the mean CPU seconds of a run.
The grammar's own `turtle arguments:` line is replaced by each setting in turn.
"""

from __future__ import annotations

import argparse
import re
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    sys.path[:0] = [str(ROOT), str(ROOT / "runtime")]
    from ngpm_runtime.grow import grow
    from ngpm_runtime.image.targets import load_target

    from ngpm_compiler.language.compile import compile_grammar

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("grammar")
    ap.add_argument("targets", help="folders of target PNGs, comma-separated")
    ap.add_argument("--ns", default="10,100,1000")
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--work", default="work/lazy_arguments")
    args = ap.parse_args()
    text = Path(args.grammar).read_text(encoding="utf-8")
    text = re.sub(r"(?im)^turtle\s+arguments\s*:.*$", "", text)
    programs = {
        how: compile_grammar(f"turtle arguments: {how}\n{text}", filename=args.grammar).program()
        for how in ("eager", "lazy")
    }
    dirs = args.targets.split(",")
    if args.targets == "envelopes":
        from ngpm_compiler.datasets.build import build_dataset

        work = Path(args.work) / Path(args.grammar).stem
        work.mkdir(parents=True, exist_ok=True)
        eager = work / Path(args.grammar).name
        eager.write_text(text, encoding="utf-8")
        dirs = []
        for seed in (2001, 2002):
            d = work / f"envelopes_{seed}_12"
            build_dataset("envelopes", d, count=12, seed=seed, grammar=eager)
            dirs.append(str(d))
    files = sorted(f for d in dirs for f in Path(d).glob("*.png"))
    targets = [load_target(f) for f in files]
    print(f"{Path(args.grammar).name}: {len(targets)} targets, {args.runs} runs each")
    for n in (int(x) for x in args.ns.split(",")):
        sims: dict[str, list[float]] = {how: [] for how in programs}
        secs: dict[str, float] = {how: 0.0 for how in programs}
        for target in targets:
            runs: dict[str, list[float]] = {how: [] for how in programs}
            for r in range(args.runs):
                for how, prog in programs.items():  # interleaved
                    t0 = time.process_time()
                    runs[how].append(grow(prog, target, None, n, args.seed + r).similarity)
                    secs[how] += time.process_time() - t0
            for how in programs:
                sims[how].append(statistics.median(runs[how]))
        k = len(targets) * args.runs
        row = ", ".join(
            f"{how} {statistics.mean(sims[how]):.3f} ({secs[how] / k:.3f} s)" for how in programs
        )
        print(f"unguided N = {n}: {row}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
