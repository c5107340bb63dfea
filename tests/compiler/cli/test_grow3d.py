"""`ngpmc grow` into 3D targets: a mesh, a saved .npz target or a picture made 3D, grown by
a 3D grammar, writing the tree's mesh and the picture target | tree; bad input is a
one-line error."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from repo_paths import REPO

from ngpm_compiler.cli import main

TOPIARY = str(REPO / "grammars" / "topiary3d.lsys")
VINES = str(REPO / "grammars" / "vines.lsys")
LINE_RE = re.compile(
    r"^(\w+): similarity (-?[\d.]+), (\d+) particles \((guided|unguided)\), "
    r"([\d.]+) s, (\d+) primitives, 16\^3 voxels$",
    re.M,
)


def cube_obj(path: Path) -> Path:
    """A closed cube (12 triangles) as Wavefront OBJ."""
    v = [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    lines = [f"v {x} {y} {z}" for x, y, z in v]
    for a, b, c, d in quads:
        lines += [f"f {a + 1} {b + 1} {c + 1}", f"f {a + 1} {c + 1} {d + 1}"]
    path.write_text("\n".join(lines) + "\n")
    return path


def grow(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["grow", *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_grow_a_mesh_writes_the_tree_and_the_picture(tmp_path: Path, capsys) -> None:
    obj = cube_obj(tmp_path / "cube.obj")
    out, png = tmp_path / "tree.glb", tmp_path / "tree.png"
    args = [str(obj), "--grammar", TOPIARY, "--guide", "none", "-N", "3", "--resolution", "16"]
    code, text, _ = grow(capsys, *args, "-o", str(out), "--png", str(png))
    assert code == 0
    m = LINE_RE.search(text)
    assert m and m.group(1) == "cube" and m.group(4) == "unguided"
    assert -1 <= float(m.group(2)) <= 1
    assert out.read_bytes()[:4] == b"glTF"
    w, h = Image.open(png).size
    assert w == 2 * h  # the target beside the tree
    # seeded: the same run again gives the same bytes
    again = tmp_path / "again.glb"
    assert grow(capsys, *args, "-o", str(again))[0] == 0
    assert again.read_bytes() == out.read_bytes()


def test_grow_a_picture_revolved_and_extruded(tmp_path: Path, capsys) -> None:
    mask = np.zeros((40, 40), np.uint8)
    mask[8:36, 12:28] = 255
    pic = tmp_path / "vase.png"
    Image.fromarray(255 - mask).save(pic)
    for flag in (["--revolve"], ["--extrude", "0.25"]):
        out = tmp_path / f"t{len(flag)}.obj"
        base = [str(pic), "--grammar", TOPIARY, "--guide", "none", "-N", "2"]
        code, text, _ = grow(capsys, *base, *flag, "--resolution", "16", "-o", str(out))
        assert code == 0 and LINE_RE.search(text), text
        assert out.is_file() and out.with_suffix(".mtl").is_file()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--grammar", VINES], "2D grammar"),
        (["--grammar", TOPIARY, "-o", "x.svg"], "a 3D grow writes"),
        (["--grammar", TOPIARY, "--png", "x.jpg"], "--png writes a .png"),
        (["--grammar", TOPIARY, "--svg"], "--svg and --steps-gif"),
        (["--grammar", TOPIARY, "--likelihood", "circuit"], "shape likelihood only"),
        (["--grammar", TOPIARY, "--extrude", "0.2"], "make pictures 3D"),
    ],
)
def test_bad_3d_grow_is_a_one_line_error(tmp_path: Path, capsys, args, message) -> None:
    obj = cube_obj(tmp_path / "cube.obj")
    code, out, err = grow(capsys, str(obj), "--guide", "none", *args)
    assert code != 0 and "Traceback" not in err
    assert [line for line in err.splitlines() if message in line] == errors(err)


@pytest.mark.parametrize(
    ("flag", "message"),
    [
        (["--png", "out.png"], "--png makes a 3D grow (a 2D grow writes its picture with -o)"),
        (["--revolve"], "--revolve makes a 3D grow"),
    ],
)
def test_a_2d_grammar_with_a_3d_option_names_the_option(
    tmp_path: Path, capsys, flag: list[str], message: str
) -> None:
    """A picture grown by a 2D grammar with --png was called "a 3D target"."""
    pic = tmp_path / "shape.png"
    Image.fromarray(np.full((20, 20), 255, np.uint8)).save(pic)
    code, _, err = grow(capsys, str(pic), "--grammar", VINES, "--guide", "none", *flag)
    assert code != 0 and "Traceback" not in err
    (line,) = errors(err)
    assert message in line and "is a 2D grammar" in line and "3D target" not in line


def errors(err: str) -> list[str]:
    """The error lines (the first run may also note that it compiles the kernels)."""
    lines = [line for line in err.splitlines() if line.startswith("ngpmc: error: ")]
    assert len(lines) == 1
    return lines


def test_a_3d_grammar_without_a_target_is_a_one_line_error(capsys) -> None:
    code, _, err = grow(capsys, "--grammar", TOPIARY)
    assert code != 0 and "give a 3D target" in errors(err)[0]
