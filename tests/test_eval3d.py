"""benchmarks/eval3d.py: the report's paired differences (guided N = 10 minus unguided at
each N, target by target) on made-up runs."""

from __future__ import annotations

from repo_paths import load_script


def load():
    return load_script("benchmarks/eval3d.py")


def run(model: str, n: int, target: str, sim: float) -> dict:
    return {"model": model, "n": n, "target": target, "similarity": sim, "seconds": 0.1}


def test_paired_differences_use_each_targets_median():
    ev = load()
    rows = []
    for t, (g, u) in enumerate(((0.6, 0.5), (0.7, 0.5), (0.4, 0.5))):
        name = f"t{t}"
        rows += [
            run(ev.GUIDED, 10, name, g),
            run(ev.GUIDED, 10, name, g),
            run(ev.GUIDED, 10, name, 0.0),
        ]
        rows += [run(ev.UNGUIDED, 100, name, u), run(ev.UNGUIDED, 100, name, u)]
    (line,) = ev.paired(rows, [100])
    # medians: guided 0.6, 0.7, 0.4 (the 0.0 runs are outvoted); differences 0.1, 0.2, -0.1
    assert line.startswith("guided N=10 - unguided N=100, per target: +0.067 +- 0.173")
    assert line.endswith("(guided higher on 2 of 3)")


def test_report_names_the_command_as_run(tmp_path):
    """The report's first line: the table's options, and only the paths that are not the
    defaults (inside the checkout relative to it, outside as given)."""
    ev = load()
    ap = ev.parser()
    plain = ev.command_line(ap, ap.parse_args(["--k", "5"]))
    assert plain == "python benchmarks/eval3d.py --k 5 --repeats 2 --ns 10,30,100,300,600"
    args = ap.parse_args(["--targets", str(ev.ROOT / "work" / "oc"), "--out", str(tmp_path)])
    line = ev.command_line(ap, args)
    assert line.endswith(f"--targets work/oc --out {tmp_path}")
    assert "--grammar" not in line and "--guide" not in line
