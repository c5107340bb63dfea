"""docs/img/3d holds a picture of every shipped 3D grammar, written by scripts/gallery3d.py
(docs/3d.md shows them); the script draws what `ngpmc sample` draws."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from PIL import Image
from repo_paths import REPO

PICTURES = REPO / "docs" / "img" / "3d"


@pytest.fixture(scope="module")
def gallery() -> ModuleType:
    spec = importlib.util.spec_from_file_location("gallery3d", REPO / "scripts" / "gallery3d.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def drawn(pic: Image.Image) -> np.ndarray:
    """True where a pixel is not the white background."""
    rgb = np.asarray(pic.convert("RGB"), dtype=np.int16)
    return (np.abs(rgb - 255).max(axis=2) > 24)


def test_every_shipped_3d_grammar_has_its_picture(gallery: ModuleType) -> None:
    names = [p.stem for p in gallery.grammars_3d()]
    assert {"bush3d", "plant3d", "tree3d", "stochastic_tree3d"} <= set(names)
    assert "vines" not in names and "bush" not in names  # 2D grammars have none
    assert gallery.missing() == []
    assert sorted(p.stem for p in PICTURES.glob("*.png")) == sorted(names), \
        "a picture in docs/img/3d for no shipped 3D grammar"
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
    assert differ < 0.005, f"plant3d.png is out of date ({differ:.2%} of pixels differ); " \
        "run python scripts/gallery3d.py"


def test_the_script_writes_and_checks_pictures(gallery: ModuleType, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
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
