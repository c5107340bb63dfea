"""README.md: the two set-up commands come first, every `ngpmc` command in it parses, every
linked or named file exists, its grammar compiles and its quick tour runs (scaled down)."""

from __future__ import annotations

import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest
from PIL import Image
from repo_paths import REPO

from ngpm_compiler.cli import build_parser, tour
from ngpm_compiler.cli.tour import commands

README = (REPO / "README.md").read_text(encoding="utf-8")
SETUP = [
    "pip install -e . && ngpmc demo -o demo_out",
    "pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu && "
    'pip install -e ".[train,eval,dev,web]" && python3 -m pytest',
]


def blocks(lang: str, text: str = README) -> list[str]:
    return tour.blocks(lang, text)


def ngpmc_lines() -> list[str]:
    lines = []
    for block in blocks("bash"):
        for line in commands(block):
            lines += [p.strip() for p in line.split("&&") if p.strip().startswith("ngpmc ")]
    return lines


def test_the_two_setup_commands_come_first() -> None:
    first = commands(blocks("bash")[0])
    assert first[:2] == SETUP
    assert README.index(SETUP[0]) < README.index("## ")  # before any section


def test_every_ngpmc_command_parses() -> None:
    lines = ngpmc_lines()
    assert len(lines) >= 15
    used = set()
    for line in lines:
        argv = shlex.split(line)[1:]
        try:
            args = build_parser().parse_args(argv)
        except SystemExit as err:
            pytest.fail(f"README command does not parse ({err}): {line}")
        assert getattr(args, "handler", None), line
        used.add(argv[0])
    assert {"demo", "grow", "check", "compile", "sample", "learn"} <= used


def test_links_and_named_files_exist() -> None:
    links = re.findall(r"\]\(([^)#]+)\)", README)
    assert "docs/img/demo.png" in links
    for doc in (
        "docs/language.md",
        "docs/architecture.md",
        "docs/datasets.md",
        "docs/api.md",
        "docs/results/",
    ):
        assert doc in links, doc
    named = re.findall(
        r"(?<![\w/])((?:grammars|scripts|runtime|docs|tests|benchmarks|\.ci)"
        r"/[\w./-]*[\w/])",
        README,
    )
    assert "scripts/train_vines_guide.sh" in named
    for rel in set(links) | set(named):
        if rel.startswith(("http://", "https://")):
            continue
        assert (REPO / rel).exists(), f"README names {rel}, which does not exist"


def test_demo_picture_is_an_image() -> None:
    """docs/img/demo.png is the demo's table (4 targets x target, guided, unguided, then
    under a header the 3D rows) and no picture in it is blank."""
    import numpy as np

    from ngpm_compiler.experiments.demo import CAPTION, CELL, HEADER, PAD
    from ngpm_compiler.experiments.demo3d import SOURCES

    with Image.open(REPO / "docs" / "img" / "demo.png") as img:
        img.verify()
    with Image.open(REPO / "docs" / "img" / "demo.png") as img:
        gray = np.asarray(img.convert("L"), dtype=np.float64)
    row = CELL + CAPTION + PAD
    n3 = len(SOURCES)
    assert gray.shape == (HEADER + 4 * row + PAD + HEADER + n3 * row, PAD + 3 * (CELL + PAD))
    tops = [HEADER + r * row for r in range(4)]
    tops += [HEADER + 4 * row + HEADER + r * row for r in range(n3)]
    for r, y0 in enumerate(tops):
        for c in range(3):
            x0 = PAD + c * (CELL + PAD)
            inner = gray[y0 + 2 : y0 + CELL - 2, x0 + 2 : x0 + CELL - 2]  # inside the frame
            drawn = (inner != np.median(inner)).mean()
            least = 0.01 if r < 4 else 0.002  # a 3D row's tree may be a stub
            assert drawn > least, f"picture {r}, {c} of demo.png looks blank ({drawn:.3f})"


def test_readme_python_runs(monkeypatch) -> None:
    (code,) = blocks("python")
    out = io.StringIO()
    monkeypatch.chdir(REPO)
    with contextlib.redirect_stdout(out):
        exec(compile(code, "README.md", "exec"), {})
    m = re.search(r"^(\d+) primitives$", out.getvalue(), re.M)
    assert m and int(m.group(1)) >= 10, out.getvalue()  # a grown vine, not an empty one


def test_quick_tour_runs_scaled_down(tmp_path: Path, monkeypatch) -> None:
    from dataclasses import replace

    from ngpm_compiler.experiments import learn

    assert [argv[0] for argv in tour.tour_commands(README)] == [
        "check",
        "compile",
        "sample",
        "learn",
        "grow",
        "grow",
    ]
    # `learn` with a plan of a few seconds (its planner is tested in tests/compiler)
    real = learn.plan

    def tiny(budget, costs):
        p = real(budget, costs)
        return replace(
            p,
            unguided_particles=8,
            guided_particles=8,
            traces=4,
            guided_traces=4,
            rounds=1,
            val_targets=1,
            val_repeats=1,
            choice_temperatures=(1.0, 0.5),
            ess=(None,),
            curve_guided=(1, 3),
            curve_unguided=(3, 10),
            more=(),
        )

    monkeypatch.setattr(learn, "plan", tiny)
    monkeypatch.setattr(learn, "replan", lambda p, left, costs, trained: p)
    monkeypatch.setattr(learn, "fill", lambda *args: None)  # no rounds added

    def smaller(argv: list[str]) -> list[str]:
        return argv + {"learn": ["--workers", "1"]}.get(argv[0], [])

    steps = tour.run_tour(README, tmp_path, smaller)
    assert [s.code for s in steps] == [0] * 6, steps[-1]
    out = "".join(s.output for s in steps)
    assert "(guided)" in out and "(unguided)" in out
    assert tour.similarity(steps[-1].output) is not None
    stem = tour.prepare(README, tmp_path)[:-5]
    for out in (
        "sample.png",
        f"{stem}.png",
        f"{stem}_prior.png",
        "out/learn/guide.onnx",
        "out/learn/report.md",
    ):
        assert (tmp_path / out).is_file(), out


def test_readme_3d_commands_run(tmp_path: Path, monkeypatch) -> None:
    """The 3D section's commands, run as written in a folder holding the grammars."""
    import shutil

    from ngpm_compiler.cli import main

    section = README[README.index("## 3D") :]
    section = section[: section.index("\n## ")]
    lines = [shlex.split(ln)[1:] for b in blocks("bash", section) for ln in commands(b)]
    assert len(lines) >= 2 and all(argv[0] == "sample" for argv in lines)
    shutil.copytree(REPO / "grammars", tmp_path / "grammars")
    monkeypatch.chdir(tmp_path)
    for argv in lines:
        assert main(argv) == 0, argv
    for name in ("tree.glb", "tree.png", "tree.obj", "turn.gif"):
        assert (tmp_path / name).stat().st_size > 1000, name
    assert "newmtl bark" in (tmp_path / "tree.mtl").read_text()
