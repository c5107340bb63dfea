"""Issue #12, command line: bad input and faults end in one clear line (no traceback),
with an exit code != 0, and nothing hangs or is lost."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from ngpm_runtime import bundled

from ngpm_compiler.cli import main

REPO = Path(__file__).resolve().parents[1]
VINES = str(REPO / "grammars" / "vines.lsys")
NGPMC = [sys.executable, "-m", "ngpm_compiler.cli"]


def run(capsys, *args: str) -> tuple[int, str, str]:
    try:
        code = main(list(args))
    except SystemExit as stop:  # argparse refuses the command line
        code = int(stop.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def error_line(capsys, *args: str) -> str:
    """The command fails with exit code != 0 and exactly one `error:` line (argparse's usage
    line may come before it), and no traceback."""
    code, _, err = run(capsys, *args)
    assert code != 0, err
    assert "Traceback" not in err
    lines = [x for x in err.strip().splitlines() if not x.startswith(("usage:", " "))]
    assert len(lines) == 1 and "error: " in lines[0], err
    return lines[0]


def cli(*args: str, timeout: float = 120, **kw) -> subprocess.CompletedProcess:
    """ngpmc in a subprocess, killed (and the test failed) if it runs past `timeout`."""
    return subprocess.run([*NGPMC, *args], capture_output=True, text=True, timeout=timeout,
                          **kw)


@pytest.fixture()
def horse(tmp_path: Path) -> Path:
    src = bundled.demo_target_path("horse")
    shutil.copy(src, tmp_path / "horse.png")
    shutil.copy(src.with_suffix(".txt"), tmp_path / "horse.txt")
    return tmp_path / "horse.png"


def write(path: Path, text: str) -> str:
    path.write_text(text, encoding="utf-8")
    return str(path)


# --------------------------------------------------------------------------- seeds


@pytest.mark.parametrize("command", [
    ["grow", "x.png"], ["sample", VINES, "-o", "x.png"], ["demo"],
    ["targets", "build", "scribbles", "-o", "x"], ["traces", VINES, "--targets", "t", "-o", "o"],
    ["train", "t", "-o", "o"], ["eval", "-o", "x"]])
def test_negative_seed_is_refused_at_parsing(capsys, command: list[str]) -> None:
    line = error_line(capsys, *command, "--seed", "-1")
    assert "--seed" in line and "seeds are integers from 0" in line and "-1" in line


def test_seed_must_be_an_integer(capsys) -> None:
    assert "not an integer" in error_line(capsys, "sample", VINES, "-o", "x.png", "--seed", "x")


# --------------------------------------------------------------------------- traces, sample


def test_traces_without_viewport_says_so(tmp_path: Path, capsys) -> None:
    g = write(tmp_path / "nv.lsys", "derivation length: 3\nAxiom: F F\nproduction:\n"
              "F --> F F : 0.5 | F : 0.5\nendlsystem\n")
    (tmp_path / "t").mkdir()
    line = error_line(capsys, "traces", g, "--targets", str(tmp_path / "t"), "-o",
                      str(tmp_path / "tr"), "-n", "1", "--workers", "1")
    assert "no 'viewport:' line" in line and "nv.lsys" in line
    assert not (tmp_path / "tr").exists()  # refused before anything was written


def test_sample_size_has_a_limit(tmp_path: Path, capsys) -> None:
    line = error_line(capsys, "sample", VINES, "--size", "20000", "-o", str(tmp_path / "s.png"))
    assert "--size" in line and "image sizes are 1 to 8192 pixels, got 20000" in line
    assert "at least" not in error_line(capsys, "sample", VINES, "--size", "0", "-o", "s.png")
    assert not (tmp_path / "s.png").exists()


# --------------------------------------------------------------------------- pipes


def test_grow_into_a_closed_pipe_still_writes_its_files(horse: Path) -> None:
    """`ngpmc grow ... | head -1`: no 'Broken pipe' error, the outputs are all written."""
    out = horse.with_name("vine.png")
    proc = subprocess.Popen([*NGPMC, "grow", str(horse), "-N", "2", "-o", str(out), "--svg",
                             "--steps-gif"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    first = proc.stdout.readline()
    proc.stdout.close()  # the reader goes away, as `head -1` does
    _, err = proc.communicate(timeout=120)
    assert first.startswith("horse: similarity")
    assert proc.returncode == 0, err
    assert "Broken pipe" not in err and "Traceback" not in err and "Exception" not in err
    for suffix in (".png", ".svg", ".gif"):
        assert out.with_suffix(suffix).stat().st_size > 0
