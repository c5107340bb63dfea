"""docs/img/3d holds a picture of every shipped 3D grammar, written by scripts/gallery3d.py;
the script draws what `ngpmc sample` draws; docs/3d.md shows them, and its commands parse and
its counts are true."""

from __future__ import annotations

import re
import shlex
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from PIL import Image
from repo_paths import REPO, load_script

PICTURES = REPO / "docs" / "img" / "3d"


@pytest.fixture(scope="module")
def gallery() -> ModuleType:
    return load_script("scripts/gallery3d.py")


def drawn(pic: Image.Image) -> np.ndarray:
    """True where a pixel is not the white background."""
    rgb = np.asarray(pic.convert("RGB"), dtype=np.int16)
    return np.abs(rgb - 255).max(axis=2) > 24


def test_every_shipped_3d_grammar_has_its_picture(gallery: ModuleType) -> None:
    names = [p.stem for p in gallery.grammars_3d()]
    assert {"bush3d", "plant3d", "tree3d", "stochastic_tree3d"} <= set(names)
    assert "vines" not in names and "bush" not in names  # 2D grammars have none
    assert gallery.missing() == []
    assert sorted(p.stem for p in PICTURES.glob("*.png")) == sorted(names), (
        "a picture in docs/img/3d for no shipped 3D grammar"
    )
    for name in names:
        with Image.open(PICTURES / f"{name}.png") as pic:
            assert pic.size == (gallery.SIZE, gallery.SIZE) and pic.mode == "P", name
            assert len(pic.getcolors()) <= gallery.COLORS, name
            mask = drawn(pic)
        assert 0.02 < mask.mean() < 0.8, f"{name}.png looks blank or full ({mask.mean():.3f})"
        rows, cols = np.nonzero(mask)
        extent = max(rows.max() - rows.min(), cols.max() - cols.min())
        assert extent > 0.8 * gallery.SIZE, name  # the plant fills the picture


def test_the_shipped_plant3d_picture_is_up_to_date(gallery: ModuleType) -> None:
    """One grammar drawn afresh at full size matches its picture (a few pixels may differ
    where floating point rounds otherwise on another machine)."""
    import io

    fresh = Image.open(io.BytesIO(gallery.picture(REPO / "grammars" / "plant3d.lsys")))
    with Image.open(PICTURES / "plant3d.png") as shipped:
        a = np.asarray(fresh.convert("RGB"), dtype=np.int16)
        b = np.asarray(shipped.convert("RGB"), dtype=np.int16)
    differ = (np.abs(a - b).max(axis=2) > 40).mean()
    assert differ < 0.005, (
        f"plant3d.png is out of date ({differ:.2%} of pixels differ); "
        "run python scripts/gallery3d.py"
    )


def test_the_script_writes_and_checks_pictures(
    gallery: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert gallery.main(["--only", "plant3d", "--size", "96", "--out", str(tmp_path)]) == 0
    assert [p.name for p in tmp_path.iterdir()] == ["plant3d.png"]
    with Image.open(tmp_path / "plant3d.png") as pic:
        assert pic.size == (96, 96) and pic.mode == "P"
        assert drawn(pic).mean() > 0.02
    assert "plant3d.png" in capsys.readouterr().out
    assert gallery.main(["--check", "--out", str(tmp_path)]) == 1
    assert "tree3d" in capsys.readouterr().out
    assert gallery.main(["--check"]) == 0
    with pytest.raises(SystemExit):
        gallery.main(["--only", "vines"])  # 2D: not in the gallery
    assert "not a shipped 3D grammar: vines" in capsys.readouterr().err


DOC = (REPO / "docs" / "3d.md").read_text(encoding="utf-8")


def test_docs_3d_commands_parse_and_links_exist() -> None:
    from ngpm_compiler.cli import build_parser

    lines = re.findall(r"`(ngpmc [^`]+)`", DOC)
    lines += [
        ln.split("#")[0].strip()
        for block in re.findall(r"```bash\n(.*?)```", DOC, re.S)
        for ln in block.splitlines()
    ]
    lines = [ln for ln in lines if ln.startswith("ngpmc sample ") and "NAME" not in ln]
    assert len(lines) >= 8
    for line in lines:
        args = build_parser().parse_args(shlex.split(line)[1:])
        assert args.handler, line
        if args.grammar.startswith("grammars/"):
            assert (REPO / args.grammar).is_file(), line
    for link in re.findall(r"\]\(([^)#]+)\)", DOC):
        assert (REPO / "docs" / link).resolve().exists(), link
    for path in sorted(PICTURES.glob("*.png")):
        assert f"](img/3d/{path.name})" in DOC, f"docs/3d.md does not show {path.name}"


def test_docs_3d_counts_are_those_of_seed_0() -> None:
    """The table's primitive and triangle counts are what `ngpmc sample` prints."""
    from ngpm_runtime import mesh_from_primitives
    from ngpm_runtime.inference.smc import forward

    from ngpm_compiler.language.compile import compile_grammar

    rows = re.findall(r"\[`(\w+)\.lsys`\].*?([\d,]+) primitives(?:, ([\d,]+) triangles)?", DOC)
    assert {r[0] for r in rows} >= {"bush3d", "plant3d", "tree3d"}
    for name, prims, tris in rows:
        got = forward(
            compile_grammar(REPO / "grammars" / f"{name}.lsys").program(), seed=0
        ).primitives
        assert len(got) == int(prims.replace(",", "")), name
        if tris:
            assert len(mesh_from_primitives(got).faces) == int(tris.replace(",", "")), name
