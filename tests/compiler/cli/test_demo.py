"""`ngpmc demo`: the README's first command, run as written in a temp dir (2D and 3D rows),
and its errors."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from blocked_imports import run_blocked
from ngpm_runtime import bundled
from PIL import Image

from ngpm_compiler.cli import main
from ngpm_compiler.experiments import demo as cmd_demo
from ngpm_compiler.experiments import demo3d

ROW_RE = re.compile(r"^\| (\w+) \| ([-\d.]+) \| ([\d.]+) \| ([-\d.]+) \| ([\d.]+) \|$")
ROW3D_RE = re.compile(r"^\| (\w+) \| ([^|]+) \| ([-\d.]+) \| ([\d.]+) \| ([-\d.]+) \| ([\d.]+) \|$")


def ngpmc(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """Run the CLI as a user would: the `ngpmc` script when installed, else the module."""
    exe = shutil.which("ngpmc")
    cmd = [exe, *args] if exe else [sys.executable, "-m", "ngpm_compiler.cli", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=cwd)


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, subprocess.CompletedProcess]:
    cwd = tmp_path_factory.mktemp("demo")
    proc = ngpmc("demo", "-o", "demo_out", cwd=cwd)
    return cwd / "demo_out", proc


def test_demo_command_as_in_readme(demo_run) -> None:
    out, proc = demo_run
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    names = list(bundled.DEMO_TARGETS)
    for name in names:
        assert name in proc.stdout
    with Image.open(out / "demo.png") as img:
        img.load()
        assert img.mode == "RGB"
        row = cmd_demo.CELL + cmd_demo.CAPTION + cmd_demo.PAD
        assert img.size == (
            cmd_demo.PAD + 3 * (cmd_demo.CELL + cmd_demo.PAD),
            cmd_demo.HEADER
            + len(names) * row
            + cmd_demo.PAD
            + cmd_demo.HEADER  # the 3D rows' header
            + len(demo3d.SOURCES) * row,
        )
        pixels = np.asarray(img)
    assert pixels.std() > 10  # not a blank picture
    for name in names:
        for kind in ("guided", "unguided"):
            with Image.open(out / f"{name}_{kind}.png") as img:
                img.verify()
    for name in demo3d.SOURCES:  # target | guided | unguided of each 3D row
        with Image.open(out / f"{name}.png") as img:
            assert img.size == (3 * 384, 384)
    assert not list(out.glob(".*tmp"))  # no temp files left behind


def test_summary_md_holds_a_row_per_target_and_matches_stdout(demo_run) -> None:
    out, proc = demo_run
    text = (out / "summary.md").read_text(encoding="utf-8")
    rows = {m.group(1): m.groups()[1:] for m in map(ROW_RE.match, text.splitlines()) if m}
    assert list(rows) == list(bundled.DEMO_TARGETS)
    for name, (gs, gt, us, ut) in rows.items():
        for sim in (float(gs), float(us)):
            assert -1.5 <= sim <= 1.0
        assert float(gt) >= 0 and float(ut) >= 0
        line = next(ln for ln in proc.stdout.splitlines() if ln.startswith(name + " "))
        assert line.split() == [name, gs, gt, us, ut]
    assert "![comparison](demo.png)" in text
    assert "3 runs per target and kind (seeds 0 to 2)" in text
    text2d = text.split("\n## 3D\n")[0]
    runs = [ln for ln in text2d.splitlines() if ln.startswith("- ")]
    assert len(runs) == len(rows)
    for line in runs:  # the table's mean is the mean of the listed runs
        name = line[2:].split(":")[0]
        guided = [float(x) for x in line.split("guided ")[1].split(";")[0].split(", ")]
        assert len(guided) == 3
        assert abs(np.mean(guided) - float(rows[name][0])) < 1.5e-3
    assert "grammar `vines`".lower() in text.lower()


def test_summary_md_holds_the_3d_rows_and_matches_stdout(demo_run) -> None:
    out, proc = demo_run
    text = (out / "summary.md").read_text(encoding="utf-8")
    head, _, section = text.partition("\n## 3D\n")
    assert section and "vines3d" in section
    assert not [ln for ln in head.splitlines() if ROW3D_RE.match(ln)]
    rows = {m.group(1): m.groups()[1:] for m in map(ROW3D_RE.match, section.splitlines()) if m}
    assert list(rows) == list(demo3d.SOURCES)
    n_u = demo3d.UNGUIDED_FACTOR * 10
    assert f"| guided N=10 | seconds | unguided N={n_u} | seconds |" in section
    table3d = proc.stdout.split("3D target", 1)[1]
    for name, (source, gs, gt, us, ut) in rows.items():
        assert source.strip() == demo3d.SOURCES[name]
        for sim in (float(gs), float(us)):
            assert -1.5 <= sim <= 1.0
        assert float(gt) >= 0 and float(ut) >= 0
        line = next(ln for ln in table3d.splitlines() if ln.startswith(name + " "))
        assert line.split() == [name, gs, gt, us, ut]
    runs = [ln for ln in section.splitlines() if ln.startswith("- ")]
    assert len(runs) == len(rows)
    for line in runs:  # the table's means are the means of the listed runs
        name = line[2:].split(" (3D):")[0]
        guided = [float(x) for x in line.split("guided ")[1].split(";")[0].split(", ")]
        unguided = [float(x) for x in line.split("unguided ")[1].split(", ")]
        assert len(guided) == len(unguided) == 3
        assert abs(np.mean(guided) - float(rows[name][1])) < 1.5e-3
        assert abs(np.mean(unguided) - float(rows[name][3])) < 1.5e-3
    mean = re.search(r"^\| \*\*mean 3D\*\* \| +\| ([-\d.]+) \|", section, re.M)
    assert mean is not None
    every = [float(r[1]) for r in rows.values()]
    assert abs(np.mean(every) - float(mean.group(1))) < 1.5e-3


def test_3d_targets_are_placed_in_the_shrubs_box() -> None:
    from ngpm_runtime.bundled import bundled_program3d

    program = bundled_program3d()
    targets = demo3d.demo_targets3d(program)
    assert [t.name for t in targets] == list(demo3d.SOURCES)
    box = np.array(program.box).reshape(3, 2)
    for t in targets:
        assert t.resolution == demo3d.RESOLUTION
        assert 0.02 < t.filled_fraction() < 0.6, t.name
        assert np.all(t.start >= box[:, 0] - 1e-9) and np.all(t.start <= box[:, 1] + 1e-9)
        assert t.occupancy[tuple(t.world_to_index(t.start + [0, t.voxel / 2, 0]))], t.name


def test_guide_beats_prior_on_the_demo_targets(demo_run) -> None:
    out, _ = demo_run
    text = (out / "summary.md").read_text(encoding="utf-8")
    rows = [m.groups() for m in map(ROW_RE.match, text.splitlines()) if m]
    guided = np.mean([float(r[1]) for r in rows])
    unguided = np.mean([float(r[3]) for r in rows])
    assert guided > unguided + 0.1, (guided, unguided)


def test_demo_is_deterministic_for_a_seed() -> None:
    a, _ = cmd_demo.run_demo(particles=3, seed=5, runs=1)
    b, _ = cmd_demo.run_demo(particles=3, seed=5, runs=1)
    for ra, rb in zip(a, b, strict=True):
        assert ra.guided.similarity == rb.guided.similarity
        assert ra.unguided.primitives == rb.unguided.primitives
    c, d = (demo3d.run_demo3d(particles=2, seed=5, runs=1) for _ in range(2))
    for rc, rd in zip(c, d, strict=True):
        assert rc.guided_runs[0].primitives == rd.guided_runs[0].primitives
        assert rc.unguided_runs[0].similarity == rd.unguided_runs[0].similarity
        assert rc.unguided_runs[0].particles == 2 * demo3d.UNGUIDED_FACTOR


def test_no_3d_leaves_the_3d_rows_out(tmp_path: Path, capsys) -> None:
    code = main(["demo", "-N", "2", "--runs", "1", "--no-3d", "-o", str(tmp_path / "out")])
    assert code == 0
    assert "3D target" not in capsys.readouterr().out
    assert "## 3D" not in (tmp_path / "out" / "summary.md").read_text(encoding="utf-8")
    assert not (tmp_path / "out" / "vase.png").exists()


# --- bad input: one line naming the problem, exit code != 0, no traceback ----------------


def one_line_error(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    return lines[0]


def test_unwritable_output_path(tmp_path: Path) -> None:
    blocker = tmp_path / "file.txt"
    blocker.write_text("not a folder")
    line = one_line_error(ngpmc("demo", "-o", str(blocker / "out"), cwd=tmp_path))
    assert "cannot write the demo output" in line and "file.txt" in line
    line = one_line_error(ngpmc("demo", "-o", str(blocker), cwd=tmp_path))
    assert "cannot write the demo output" in line


def test_bad_particle_count(tmp_path: Path) -> None:
    """Refused by argparse (exit code 2), after its usage line."""
    proc = ngpmc("demo", "-N", "0", "-o", "x", cwd=tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "argument -N/--particles: must be from 1 to" in proc.stderr.splitlines()[-1]
    proc = ngpmc("demo", "--runs", "0", "-o", "x", cwd=tmp_path)
    assert proc.returncode == 2 and "argument --runs: must be from 1 to" in proc.stderr
    assert not (tmp_path / "x").exists()


def test_missing_bundled_guide(tmp_path: Path, monkeypatch, capsys) -> None:
    data = tmp_path / "data"
    data.mkdir()
    shutil.copy(bundled.sampler_path(), data / bundled.SAMPLER_FILE)
    monkeypatch.setattr(bundled, "DATA_DIR", data)
    code = main(["demo", "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code != 0
    assert err.count("\n") == 1 and "bundled vines guide is missing" in err
    assert not (tmp_path / "out").exists()  # checked before anything is written


def test_foreign_bundled_guide(tmp_path: Path, monkeypatch, capsys) -> None:
    data = tmp_path / "data"
    data.mkdir()
    shutil.copy(bundled.sampler_path(), data / bundled.SAMPLER_FILE)
    (data / bundled.GUIDE_FILE).write_bytes(b"not an onnx file at all")
    monkeypatch.setattr(bundled, "DATA_DIR", data)
    code = main(["demo", "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code != 0
    assert err.count("\n") == 1 and "not a readable ONNX guide" in err


def test_missing_bundled_3d_guide(tmp_path: Path, monkeypatch, capsys) -> None:
    data = tmp_path / "data"
    data.mkdir()
    for name in (bundled.SAMPLER_FILE, bundled.GUIDE_FILE):
        shutil.copy(bundled.data_path(name), data / name)
    monkeypatch.setattr(bundled, "DATA_DIR", data)
    code = main(["demo", "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code != 0
    # one line (after the kernels' compile notice when their cache is cold)
    assert "Traceback" not in err and "bundled 3D guide is missing" in err.splitlines()[-1]
    assert not (tmp_path / "out").exists()  # checked before anything is written


NO_TORCH = """
from ngpm_compiler.cli import main
code = main(["demo", "-N", "2", "-o", sys.argv[1]])
assert code == 0, code
"""


def test_demo_runs_without_torch(tmp_path: Path) -> None:
    """`pip install .` without extras (no torch, scipy, scikit-image or matplotlib; onnx is
    optional at run time): the demo still works."""
    proc = run_blocked(
        NO_TORCH,
        tmp_path,
        str(tmp_path / "out"),
        blocked=("torch", "onnx", "scipy", "skimage", "matplotlib"),
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (tmp_path / "out" / "demo.png").is_file()
    assert (tmp_path / "out" / "vase.png").is_file()  # the 3D rows too
