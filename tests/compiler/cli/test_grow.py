"""`ngpmc grow IMAGE -o out.png`: the bundled vines guide by default, --grammar, --guide,
--likelihood, --svg, --steps-gif; and bad input as one-line errors through the CLI."""

from __future__ import annotations

import re
import resource
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fixtures.pictures import house
from ngpm_runtime import bundled
from PIL import Image
from repo_paths import REPO

from ngpm_compiler.cli import main

VINES = str(REPO / "grammars" / "vines.lsys")
CHAIN = str(REPO / "grammars" / "chain.lsys")
LINE_RE = re.compile(
    r"^(\w+): similarity (-?[\d.]+), (\d+) particles \((guided|unguided)\), "
    r"([\d.]+) s, (\d+) primitives$",
    re.M,
)


@pytest.fixture(autouse=True)
def in_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """grow writes IMAGE_grown.png in the current folder by default: keep it in tmp_path."""
    monkeypatch.chdir(tmp_path)


def run(capsys, *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(capsys, *args: str) -> str:
    code, _, err = run(capsys, *args)
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ngpmc: error: "), err
    return lines[0]


def test_grow_image_with_the_bundled_guide(horse: Path, capsys) -> None:
    out = horse.with_name("vine.png")
    code, text, _ = run(capsys, "grow", str(horse), "-o", str(out))
    assert code == 0
    m = LINE_RE.search(text)
    assert m, text
    name, sim, n, kind, secs, prims = m.groups()
    assert (name, n, kind) == ("horse", "10", "guided")
    assert 0.0 < float(sim) <= 1.0 and float(secs) > 0 and int(prims) > 0
    assert "vines_guide.onnx" in text
    with Image.open(out) as img:
        img.verify()


def test_without_o_the_render_goes_beside_in_the_current_folder(horse: Path, capsys) -> None:
    code, text, _ = run(capsys, "grow", str(horse), "-N", "3", "--svg")
    assert code == 0
    assert "wrote horse_grown.png" in text and "wrote horse_grown.svg" in text
    with Image.open(Path("horse_grown.png")) as img:
        img.verify()
    help_text = build_parser_help("grow")
    assert "IMAGE_grown.png in the current folder" in help_text


def build_parser_help(command: str) -> str:
    from ngpm_compiler.cli import build_parser

    sub = build_parser()._subparsers._group_actions[0].choices[command]
    return " ".join(sub.format_help().split())


def test_svg_and_growth_animation_beside_the_render(horse: Path, capsys) -> None:
    out = horse.with_name("vine.png")
    code, text, _ = run(
        capsys, "grow", str(horse), "-o", str(out), "--svg", "--steps-gif", "-N", "4"
    )
    assert code == 0, text
    assert out.with_suffix(".svg").read_text().startswith("<svg")
    prims = int(LINE_RE.search(text).group(6))
    with Image.open(out.with_suffix(".gif")) as gif:
        assert gif.n_frames == min(prims, 59) + 1  # empty canvas, then the growth
        assert gif.info.get("loop") == 0
    gif2 = horse.with_name("steps.gif")
    assert run(capsys, "grow", str(horse), "--steps-gif", str(gif2), "-N", "2")[0] == 0
    with Image.open(gif2) as gif:
        assert gif.n_frames > 1


def test_same_seed_same_result(horse: Path, capsys) -> None:
    """The same seed writes the same vine (identical SVG, identical pixels); another seed
    another one."""
    outs = {}
    for name, seed in (("a", "7"), ("b", "7"), ("c", "8")):
        out = horse.with_name(f"{name}.svg")
        code, text, _ = run(capsys, "grow", str(horse), "-N", "3", "--seed", seed, "-o", str(out))
        assert code == 0 and LINE_RE.search(text), text
        outs[name] = out.read_text()
    assert outs["a"] == outs["b"] and outs["a"] != outs["c"]
    assert outs["a"].count("<line") + outs["a"].count("<path") + outs["a"].count("<ellipse") > 0
    pngs = []
    for name in ("a", "b"):
        out = horse.with_name(f"{name}.png")
        assert run(capsys, "grow", str(horse), "-N", "3", "--seed", "7", "-o", str(out))[0] == 0
        with Image.open(out) as img:
            pngs.append(img.tobytes())
    assert pngs[0] == pngs[1]


def test_guide_choices(horse: Path, capsys) -> None:
    code, text, _ = run(capsys, "grow", str(horse), "--guide", "none", "-N", "3")
    assert code == 0 and "(unguided)" in text
    # the same grammar compiled from source still gets the bundled guide (same hash)
    code, text, _ = run(capsys, "grow", str(horse), "--grammar", VINES, "-N", "3")
    assert code == 0 and "(guided)" in text
    code, text, _ = run(capsys, "grow", str(horse), "--guide", str(bundled.guide_path()), "-N", "3")
    assert code == 0 and "(guided)" in text
    # another grammar has no default guide
    code, text, _ = run(capsys, "grow", str(horse), "--grammar", CHAIN, "-N", "3")
    assert code == 0 and "no bundled guide for grammar chain" in text and "(unguided)" in text


def test_circuit_likelihood_needs_no_image_and_takes_the_circuit_guide(capsys) -> None:
    code, text, _ = run(capsys, "grow", "--likelihood", "circuit", "-N", "3")
    assert code == 0
    assert re.search(
        r"^vines: circuit score [\d.]+ \(log-likelihood -?[\d.]+\), 3 particles \(guided\)",
        text,
        re.M,
    ), text
    circuit = bundled.data_path(bundled.CIRCUIT_GUIDE_FILE)
    assert f"guide: {circuit}" in text  # the circuit guide, never the shape guide
    code, text, _ = run(capsys, "grow", "--likelihood", "circuit", "-N", "3", "--guide", "none")
    assert code == 0 and "(unguided)" in text and "guide:" not in text
    # a guide given explicitly is still used
    code, text, _ = run(
        capsys, "grow", "--likelihood", "circuit", "-N", "3", "--guide", str(bundled.guide_path())
    )
    assert code == 0 and "(guided)" in text and f"guide: {bundled.guide_path()}" in text
    # another grammar has no bundled circuit guide: unguided, saying so
    chain = str(REPO / "grammars" / "chain.lsys")
    code, text, _ = run(capsys, "grow", "--likelihood", "circuit", "-N", "3", "--grammar", chain)
    assert code == 0 and "no bundled guide for grammar chain with the circuit" in text


# --- bad input ---------------------------------------------------------------------------


def test_missing_and_unreadable_images(tmp_path: Path, capsys) -> None:
    line = one_line_error(capsys, "grow", str(tmp_path / "nope.png"))
    assert "nope.png does not exist" in line
    fake = tmp_path / "fake.png"
    fake.write_text("this is not an image")
    assert "cannot read target image" in one_line_error(capsys, "grow", str(fake))
    assert "give a target image" in one_line_error(capsys, "grow")


def test_a_tall_tiny_png_is_refused_before_it_takes_memory(tmp_path: Path) -> None:
    """Issue #27 finding 6: a 8 x 60000 PNG of 200 bytes made `ngpmc grow` pad it to a
    60000 x 60000 square (3.35 GiB; a MemoryError traceback under a memory limit). Run
    here under a 2 GiB address-space limit: one line naming the file and the limit."""
    pixels = np.full((60000, 8), 255, np.uint8)
    pixels[:30000, 2:6] = 0
    tall = tmp_path / "tall.png"
    Image.fromarray(pixels).convert("1").save(tall)

    def two_gib() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (2 * 2**30, 2 * 2**30))

    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "ngpm_compiler.cli",
            "grow",
            str(tall),
            "-o",
            str(tmp_path / "v.png"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=two_gib,
    )
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.strip() == (
        f"ngpmc: error: cannot read target image {tall}: the image "
        "is 8 x 60000 px; the limit is 8192 px a side and "
        "33,554,432 px in all"
    )


def test_grammar_given_as_the_image(capsys) -> None:
    line = one_line_error(capsys, "grow", VINES)
    assert "is a grammar, not an image" in line and "--grammar" in line


def test_guide_for_another_grammar(horse: Path, capsys) -> None:
    line = one_line_error(
        capsys, "grow", str(horse), "--grammar", CHAIN, "--guide", str(bundled.guide_path())
    )
    assert "trained for grammar 'vines'" in line


def test_corrupt_guide_and_missing_grammar(horse: Path, capsys) -> None:
    bad = horse.with_name("bad.onnx")
    bad.write_bytes(b"\x00" * 50)
    assert "not a readable ONNX guide" in one_line_error(
        capsys, "grow", str(horse), "--guide", str(bad)
    )
    line = one_line_error(capsys, "grow", str(horse), "--grammar", "nowhere/x.lsys")
    assert "no such grammar file" in line


def test_unwritable_or_wrong_outputs(horse: Path, capsys) -> None:
    out = horse.with_name("vine.png")
    line = one_line_error(capsys, "grow", str(horse), "-o", str(horse.parent / "no" / "v.png"))
    assert "cannot write there" in line
    assert "must be a .png or .svg" in one_line_error(
        capsys, "grow", str(horse), "-o", str(horse.with_name("v.jpg"))
    )
    folder = horse.with_name("folder.png")
    folder.mkdir()
    assert "is a folder" in one_line_error(capsys, "grow", str(horse), "-o", str(folder))
    assert "writes a .gif file" in one_line_error(
        capsys, "grow", str(horse), "-o", str(out), "--steps-gif", str(out)
    )
    with pytest.raises(SystemExit, match="2"):
        main(["grow", str(horse), "-N", "0"])
    assert "argument -N/--particles: must be from 1 to" in capsys.readouterr().err
    assert not out.exists()


def test_errors_through_the_installed_command(tmp_path: Path) -> None:
    exe = shutil.which("ngpmc")
    cmd = [exe] if exe else [sys.executable, "-m", "ngpm_compiler.cli"]
    fake = tmp_path / "fake.png"
    fake.write_text("no image")
    proc = subprocess.run(
        [*cmd, "grow", str(fake), "-o", str(tmp_path / "v.png")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert proc.stderr.count("\n") == 1 and "fake.png" in proc.stderr


def test_thin_strokes_lost_at_the_working_size_are_warned_about(tmp_path: Path, capsys) -> None:
    thin = house(tmp_path / "house.png", 8)
    code, text, _ = run(capsys, "grow", str(thin), "-N", "2")
    assert code == 0
    assert re.search(
        r"^warning: only \d+% of the picture's shape is kept at 50 x 50 pixels "
        r".*draw thicker strokes, or grow at --size 128 "
        r"\(guides trained at 50 x 50 guide less well there\)$",
        text,
        re.M,
    ), text
    code, text, _ = run(capsys, "grow", str(thin), "-N", "2", "--size", "128")
    assert code == 0 and "warning" not in text
    thick = house(tmp_path / "thick.png", 40)
    code, text, _ = run(capsys, "grow", str(thick), "-N", "2")
    assert code == 0 and "warning" not in text
    line = one_line_error(capsys, "grow", str(house(tmp_path / "hair.png", 1)))
    assert "no shape left at 50 x 50 px; draw thicker strokes" in line


def test_a_low_similarity_is_explained(horse: Path, capsys) -> None:
    code, text, _ = run(capsys, "grow", str(horse), "-N", "1", "--guide", "none", "--seed", "1")
    sim = float(LINE_RE.search(text).group(2))
    explained = "similarity: 1 = the target exactly, 0 = no better than a blank canvas" in text
    assert code == 0 and explained == (sim < 0.2), text


@pytest.mark.parametrize("guide", [[], ["--guide", "none"]])
def test_grow_a_picture_with_a_3d_grammar_asks_to_make_it_3d(
    horse: Path, guide: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    """A 3D grammar grows into a 3D target: a plain picture is refused, in one line,
    naming --extrude and --revolve (tests/compiler/cli/test_grow3d.py grows 3D)."""
    tree = str(REPO / "grammars" / "tree3d.lsys")
    assert main(["grow", str(horse), "--grammar", tree, "-o", "x.png", *guide]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("ngpmc: error: ") and "--extrude" in err and "--revolve" in err
    assert "\n" not in err and not Path("x.png").exists()
