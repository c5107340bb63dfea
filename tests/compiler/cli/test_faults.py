"""Issue #12, command line: bad input and faults end in one clear line (no traceback),
with an exit code != 0, and nothing hangs or is lost."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from ngpm_runtime import bundled
from repo_paths import REPO

from ngpm_compiler.cli import main

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
    return subprocess.run([*NGPMC, *args], capture_output=True, text=True, timeout=timeout, **kw)


def write(path: Path, text: str) -> str:
    path.write_text(text, encoding="utf-8")
    return str(path)


# --------------------------------------------------------------------------- seeds


@pytest.mark.parametrize(
    "command",
    [
        ["grow", "x.png"],
        ["sample", VINES, "-o", "x.png"],
        ["demo"],
        ["targets", "build", "scribbles", "-o", "x"],
        ["traces", VINES, "--targets", "t", "-o", "o"],
        ["train", "t", "-o", "o.pt"],
        ["eval", "-o", "x"],
    ],
)
def test_negative_seed_is_refused_at_parsing(capsys, command: list[str]) -> None:
    line = error_line(capsys, *command, "--seed", "-1")
    assert "--seed" in line and "seeds are integers from 0" in line and "-1" in line


def test_seed_must_be_an_integer(capsys) -> None:
    assert "not an integer" in error_line(capsys, "sample", VINES, "-o", "x.png", "--seed", "x")


# --------------------------------------------------------------------------- traces, sample


def test_traces_without_viewport_says_so(tmp_path: Path, capsys) -> None:
    g = write(
        tmp_path / "nv.lsys",
        "derivation length: 3\nAxiom: F F\nproduction:\nF --> F F : 0.5 | F : 0.5\nendlsystem\n",
    )
    (tmp_path / "t").mkdir()
    line = error_line(
        capsys,
        "traces",
        g,
        "--targets",
        str(tmp_path / "t"),
        "-o",
        str(tmp_path / "tr"),
        "-n",
        "1",
        "--workers",
        "1",
    )
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
    proc = subprocess.Popen(
        [*NGPMC, "grow", str(horse), "-N", "2", "-o", str(out), "--svg", "--steps-gif"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    first = proc.stdout.readline()
    proc.stdout.close()  # the reader goes away, as `head -1` does
    _, err = proc.communicate(timeout=120)
    assert first.startswith("horse: similarity")
    assert proc.returncode == 0, err
    assert "Broken pipe" not in err and "Traceback" not in err and "Exception" not in err
    for suffix in (".png", ".svg", ".gif"):
        assert out.with_suffix(suffix).stat().st_size > 0


# --------------------------------------------------------------------------- hangs


def test_traces_stops_when_every_job_is_dropped(tmp_path: Path) -> None:
    """`Axiom: F F F` never reaches a keep threshold of 10 primitives (--min-primitives 10;
    by default it is kept): traces stops with a message that says why and what to change,
    and keeps its manifest."""
    g = write(tmp_path / "f3.lsys", "viewport: -10 10 -10 10\nAxiom: F F F\nendlsystem\n")
    data = tmp_path / "sc"
    assert cli("targets", "build", "scribbles", "-o", str(data), "--count", "2").returncode == 0
    proc = cli(
        "traces",
        g,
        "--targets",
        str(data),
        "-n",
        "3",
        "--particles",
        "4",
        "-o",
        str(tmp_path / "tr"),
        "--workers",
        "1",
        "--min-primitives",
        "10",
        timeout=120,
    )
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert "stopped after 50 jobs in a row were dropped" in last
    assert "fewer than 10 primitives" in last and "make the grammar draw more" in last
    assert (tmp_path / "tr" / "manifest.json").is_file()


EXPONENTIAL = (
    "viewport: -10 10 -10 10\nderivation length: 60\nAxiom: A\nproduction:\nA --> A A\nendlsystem\n"
)


def test_exponential_grammar_stops_at_the_module_cap(tmp_path: Path, horse: Path) -> None:
    g = write(tmp_path / "exp.lsys", EXPONENTIAL)
    proc = cli(
        "grow", str(horse), "--grammar", g, "-N", "10", "-o", str(tmp_path / "e.png"), timeout=60
    )
    assert proc.returncode == 0, proc.stderr
    assert "0 primitives" in proc.stdout
    assert "status limit: max modules (20000 modules" in proc.stdout
    assert "--max-modules" in proc.stdout
    proc = cli("sample", g, "--max-modules", "500", "-o", str(tmp_path / "s.png"), timeout=60)
    assert proc.returncode == 0 and "status limit" in proc.stdout
    assert "max modules (500 modules" in proc.stdout


def test_max_modules_header_sets_the_cap(tmp_path: Path) -> None:
    g = write(tmp_path / "exp.lsys", EXPONENTIAL.replace("Axiom", "max modules: 300\nAxiom"))
    proc = cli("sample", g, "-o", str(tmp_path / "s.png"), timeout=60)
    assert proc.returncode == 0 and "max modules (300 modules" in proc.stdout


def test_traces_on_an_exponential_grammar_ends(tmp_path: Path) -> None:
    g = write(tmp_path / "exp.lsys", EXPONENTIAL)
    data = tmp_path / "sc"
    assert cli("targets", "build", "scribbles", "-o", str(data), "--count", "2").returncode == 0
    proc = cli(
        "traces",
        g,
        "--targets",
        str(data),
        "-n",
        "2",
        "--particles",
        "20",
        "-o",
        str(tmp_path / "tr"),
        "--workers",
        "1",
        timeout=120,
    )
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert "samples stop at the 'max modules' cap (20000 modules expanded" in last
    assert "the grammar expands without drawing" in last
    manifest = json.loads((tmp_path / "tr" / "manifest.json").read_text())
    assert manifest["dropped"] == 5 and manifest["kept"] == 0


def test_module_cap_option_is_checked(capsys) -> None:
    assert "argument --max-modules: must be from 1 to" in error_line(
        capsys, "sample", VINES, "-o", "x.png", "--max-modules", "0"
    )


def test_traces_killed_by_timeout_exits_promptly(tmp_path: Path) -> None:
    """SIGTERM to the whole process group, as `timeout 60 ngpmc traces ...` sends it: the
    main process exits within seconds (it used to hang in Pool.terminate) with the
    manifest written."""
    import os
    import signal
    import time

    data = tmp_path / "sc"
    assert cli("targets", "build", "scribbles", "-o", str(data), "--count", "2").returncode == 0
    for i, delay in enumerate((4.0, 5.5)):
        out = tmp_path / f"tr{i}"
        proc = subprocess.Popen(
            [
                *NGPMC,
                "traces",
                VINES,
                "--targets",
                str(data),
                "-n",
                "500",
                "--particles",
                "30",
                "--shard-size",
                "3",
                "-o",
                str(out),
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        time.sleep(delay)
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            _, err = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            pytest.fail("ngpmc traces hung after SIGTERM")
        assert proc.returncode != 0 and "Traceback" not in err
        assert (out / "manifest.json").is_file()


# --------------------------------------------------------------------------- data loss


@pytest.fixture(scope="module")
def traces_dir(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("traces")
    data = tmp / "sc"
    assert cli("targets", "build", "scribbles", "-o", str(data), "--count", "2").returncode == 0
    out = tmp / "tr"
    proc = cli(
        "traces",
        str(REPO / "grammars" / "chain.lsys"),
        "--targets",
        str(data),
        "-n",
        "6",
        "--particles",
        "4",
        "--shard-size",
        "2",
        "--workers",
        "1",
        "-o",
        str(out),
    )
    assert proc.returncode == 0, proc.stderr
    return out


def test_train_stops_on_a_missing_shard(traces_dir: Path, tmp_path: Path, capsys) -> None:
    tr = tmp_path / "tr"
    shutil.copytree(traces_dir, tr)
    shards = sorted(tr.glob("shard_*.npz"))
    assert len(shards) >= 2
    shards[0].unlink()
    model = tmp_path / "m.pt"
    line = error_line(capsys, "train", str(tr), "-o", str(model), "--epochs", "1")
    assert f"missing {shards[0].name}" in line and "--allow-missing" in line
    assert "kept traces are there" in line and not model.exists()
    shards[1].write_bytes(b"not a shard")
    line = error_line(capsys, "train", str(tr), "-o", str(model), "--epochs", "1")
    assert f"unreadable {shards[1].name}" in line
    code, _, err = run(
        capsys, "train", str(tr), "-o", str(model), "--epochs", "1", "--allow-missing"
    )
    assert code == 0 and "warning" in err and model.is_file()


def test_train_checks_its_output_before_training(traces_dir: Path, tmp_path: Path, capsys) -> None:
    (tmp_path / "existing.pt").mkdir()
    line = error_line(capsys, "train", str(traces_dir), "-o", str(tmp_path / "existing.pt"))
    assert "is a folder; -o wants the model file to write" in line
    line = error_line(capsys, "train", str(traces_dir), "-o", str(tmp_path / "no" / "m.pt"))
    assert "cannot write there (no folder" in line
    (tmp_path / "existing.onnx").mkdir()
    line = error_line(capsys, "export", "m.pt", "-o", str(tmp_path / "existing.onnx"))
    assert "is a folder; -o wants the ONNX file to write" in line


# --------------------------------------------------------------------------- messages


@pytest.mark.parametrize(
    "successor, col, words",
    [
        ("F ] B : 0.5 | F [ + B ] : 0.5", 9, "unmatched ']' in rule for B: no '[' before it"),
        ("F B : 0.5 | F [ + B : 0.5", 21, "unmatched '[' in rule for B: no ']' closes it"),
    ],
)
def test_check_finds_unmatched_brackets(
    tmp_path: Path, successor: str, col: int, words: str
) -> None:
    g = write(
        tmp_path / "br.lsys",
        "viewport: -10 10 -10 10\nderivation length: 4\n"
        f"Axiom: B\nproduction:\nB --> {successor}\nendlsystem\n",
    )
    for command in (["check", g], ["sample", g, "-o", str(tmp_path / "s.png")]):
        proc = cli(*command, timeout=60)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr
        head, line, caret = proc.stderr.strip().splitlines()
        assert head == f"ngpmc: error: {g}:5:{col}: {words}"
        assert line == f"B --> {successor}" and caret == " " * (col - 1) + "^"


@pytest.fixture()
def bare_images(tmp_path: Path) -> Path:
    """A folder of two pictures without sidecars and without index.json."""
    folder = tmp_path / "pictures"
    folder.mkdir()
    for name in ("horse", "heart"):
        shutil.copy(bundled.demo_target_path(name), folder / f"{name}.png")
    return folder


def test_folder_without_sidecars_loads_with_automatic_starts(
    bare_images: Path, tmp_path: Path, capsys
) -> None:
    from ngpm_runtime.image.targets import Target, auto_start, load_dataset

    targets = load_dataset(bare_images)
    assert [t.name for t in targets] == ["heart", "horse"]
    assert all(t.start == Target(t.mask, auto_start(t.mask)).start for t in targets)
    code, out, err = run(
        capsys, "targets", "show", str(bare_images), "-o", str(tmp_path / "sheet.png")
    )
    assert code == 0 and "2 of 2 targets" in out, err
    proc = cli(
        "traces",
        str(REPO / "grammars" / "chain.lsys"),
        "--targets",
        str(bare_images),
        "-n",
        "2",
        "--particles",
        "4",
        "--workers",
        "1",
        "-o",
        str(tmp_path / "tr"),
    )
    assert proc.returncode == 0 and "2 traces kept" in proc.stdout, proc.stderr


def test_grow_says_it_wants_an_image_not_a_folder(bare_images: Path, capsys) -> None:
    line = error_line(capsys, "grow", str(bare_images), "-o", "x.png")
    assert line == (
        f"ngpmc: error: {bare_images} is a folder: grow wants one target image "
        "(ngpmc grow IMAGE -o vine.png), so run it once per image"
    )


def test_errors_name_the_users_path_not_a_temp_file(tmp_path: Path, capsys) -> None:
    from ngpm_runtime.files import atomic_write

    target = tmp_path / "existing_dir.onnx"
    target.mkdir()
    with pytest.raises(IsADirectoryError) as info:
        atomic_write(target, b"data")
    assert info.value.filename == str(target) and ".tmp" not in str(info.value)
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_o_on_a_symlink_writes_through_to_its_target(tmp_path: Path, horse: Path, capsys) -> None:
    """Issue #27, finding 8: `-o LINK` replaces the file the link points to (atomically,
    beside that file); the link stays a link. A link loop is one error line."""
    real = tmp_path / "kept" / "sheet.png"
    real.parent.mkdir()
    real.write_bytes(b"old")
    link = tmp_path / "link.png"
    link.symlink_to(real)
    code, _, err = run(capsys, "targets", "show", str(horse), "-o", str(link))
    assert code == 0, err
    assert link.is_symlink() and link.readlink() == real
    assert real.read_bytes().startswith(b"\x89PNG")
    assert not [p for p in tmp_path.rglob("*") if p.name.endswith(".tmp")]
    loop = tmp_path / "loop.png"
    loop.symlink_to(loop)
    line = error_line(capsys, "targets", "show", str(horse), "-o", str(loop))
    assert line == f"ngpmc: error: Too many levels of symbolic links: {loop}"
    assert loop.is_symlink()


def test_compile_o_wants_a_folder(tmp_path: Path, capsys) -> None:
    out = tmp_path / "vines_sampler.py"
    out.write_text("# mine\n")
    line = error_line(capsys, "compile", VINES, "-o", str(out))
    assert line == (
        f"ngpmc: error: {out}: is a file; -o wants a folder (the outputs are "
        "named after the grammar)"
    )
    assert out.read_text() == "# mine\n"


def test_animated_gif_uses_its_first_frame_with_a_shape(
    tmp_path: Path, horse: Path, capsys
) -> None:
    from ngpm_runtime.image.targets import load_target, read_image
    from PIL import Image

    shape = Image.open(horse).convert("RGB")
    blank = Image.new("RGB", shape.size, (255, 255, 255))
    gif = tmp_path / "anim.gif"
    blank.save(gif, save_all=True, append_images=[shape], duration=100, loop=0)
    assert read_image(gif).info["ngpm_frame"] == 1
    assert load_target(gif).mask.any()
    code, out, err = run(capsys, "grow", str(gif), "-N", "2", "-o", str(tmp_path / "g.png"))
    assert code == 0 and "anim: similarity" in out, err
    gray = Image.new("RGB", shape.size, (128, 128, 128))
    blank.save(gif, save_all=True, append_images=[gray], duration=100, loop=0)
    line = error_line(capsys, "grow", str(gif), "-o", str(tmp_path / "g.png"))
    assert "none of the animation's 2 frames holds a shape" in line


def test_grow_with_a_damaged_or_newer_guide(tmp_path: Path, horse: Path, capsys) -> None:
    import onnx

    model = onnx.load(str(bundled.guide_path()))
    keep = [o for o in model.graph.output if o.name != "p_1"]
    del model.graph.output[:]
    model.graph.output.extend(keep)
    damaged = tmp_path / "damaged.onnx"
    onnx.save(model, str(damaged))
    line = error_line(capsys, "grow", str(horse), "--guide", str(damaged))
    assert line.startswith(f"ngpmc: error: {damaged}: the ONNX graph has no output p_1")
    model = onnx.load(str(bundled.guide_path()))
    for prop in model.metadata_props:
        if prop.key == "ngpm_format":
            prop.value = "ngpm-guide-onnx/7"
    newer = tmp_path / "newer.onnx"
    onnx.save(model, str(newer))
    line = error_line(capsys, "grow", str(horse), "--guide", str(newer))
    assert "guide format ngpm-guide-onnx/7 is newer than the ngpm-guide-onnx/1" in line
    assert "not an ngpm guide" not in line
