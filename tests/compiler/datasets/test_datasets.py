"""Tests for ngpm_compiler.datasets: scribbles, glyphs, silhouettes, builds, sheets."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from ngpm_runtime.errors import TargetError
from ngpm_runtime.image.targets import Target, load_dataset, load_target
from PIL import Image, ImageFont
from skimage.measure import label
from skimage.morphology import skeletonize

from ngpm_compiler.datasets import build as datasets
from ngpm_compiler.datasets.build import build_dataset
from ngpm_compiler.datasets.common import DatasetError, DatasetWarning
from ngpm_compiler.datasets.glyphs import default_font, font_codepoints, glyph_ok, render_glyph
from ngpm_compiler.datasets.scribbles import scribble
from ngpm_compiler.datasets.sheets import contact_sheet
from ngpm_compiler.datasets.silhouettes import SHAPE_KINDS, fit_mask, procedural_silhouette


def rng(i: int, seed: int = 0) -> np.random.Generator:
    return np.random.default_rng([seed, i])


# --- scribbles ---------------------------------------------------------------------------


def test_scribbles_are_valid_and_reproducible():
    shapes = [scribble(rng(i)) for i in range(40)]
    for t in shapes:
        assert t.mask.shape == (50, 50)
        assert label(t.mask, connectivity=2).max() == 1
        assert 0.03 <= t.mask.mean() <= 0.45
        assert t.mask[t.start_pixel()]  # the stroke begins inside the mask
        assert np.hypot(t.start[2], t.start[3]) == pytest.approx(1.0)
    again = scribble(rng(7))
    assert np.array_equal(again.mask, shapes[7].mask) and again.start == shapes[7].start
    other = scribble(rng(7, seed=1))
    assert not np.array_equal(other.mask, shapes[7].mask)


def test_scribbles_vary_in_thickness_and_direction():
    shapes = [scribble(rng(i)) for i in range(40)]
    thickness = [t.mask.sum() / max(1, skeletonize(t.mask).sum()) for t in shapes]
    assert min(thickness) < 3.0 and max(thickness) > 6.0  # thin and thick strokes
    ups = sum(t.start[3] < -0.5 for t in shapes)
    assert 15 <= ups < 40  # mostly upward starts, but not all
    loops = sum(label(~t.mask, connectivity=1).max() > 1 for t in shapes)
    assert 5 <= loops < 40  # some strokes cross themselves and enclose background


def test_scribbles_other_size():
    t = scribble(rng(3), size=96)
    assert t.mask.shape == (96, 96) and t.mask[t.start_pixel()]


# --- glyphs ------------------------------------------------------------------------------


def test_glyph_filter_one_component_and_enough_pixels():
    face = ImageFont.truetype(str(default_font()), 200)
    assert glyph_ok(render_glyph(face, "A", 50)) is None
    assert "2 connected" in glyph_ok(render_glyph(face, "i", 50))
    assert "pixels" in glyph_ok(render_glyph(face, ".", 50))
    two = np.zeros((50, 50), bool)
    two[10:40, 5:15] = True
    two[10:40, 30:40] = True
    assert "2 connected" in glyph_ok(two)
    diag = np.zeros((50, 50), bool)  # touching at a corner: one component (8-connected)
    diag[10:25, 10:25] = True
    diag[25:40, 25:40] = True
    assert glyph_ok(diag) is None


def test_glyph_dataset_filters_and_counts(tmp_path):
    files = build_dataset("glyphs", tmp_path, count=60)
    assert len(files) == 60
    index = json.loads((tmp_path / "index.json").read_text())
    chars = [s.split()[-1] for s in index["sources"]]
    assert "A" in chars and "Q" in chars
    assert not {"i", "j", ";", ":", "%", ".", "!", "?", "="} & set(chars)
    for t in load_dataset(tmp_path):
        assert label(t.mask, connectivity=2).max() == 1 and t.mask.mean() >= 0.04
        assert t.mask[t.start_pixel()]


def test_glyphs_with_other_font(tmp_path):
    serif = default_font().with_name("DejaVuSerif.ttf")
    files = build_dataset("glyphs", tmp_path, count=5, font=serif)
    index = json.loads((tmp_path / "index.json").read_text())
    assert len(files) == 5 and index["font"] == str(serif)
    assert index["sources"][0].startswith("DejaVuSerif.ttf")


def test_reading_a_fonts_code_points_closes_the_file():
    """fontTools kept the font file open; its ResourceWarning, raised whenever the garbage
    collector ran, landed in a later test's recorded warnings."""
    import gc
    import warnings

    serif = default_font().with_name("DejaVuSerif.ttf")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ResourceWarning)
        assert len(font_codepoints(serif)) > 100
        gc.collect()
    assert not [w for w in caught if issubclass(w.category, ResourceWarning)]


def test_bad_font(tmp_path):
    with pytest.raises(DatasetError, match="does not exist"):
        build_dataset("glyphs", tmp_path / "a", font=tmp_path / "nope.ttf")
    bad = tmp_path / "bad.ttf"
    bad.write_bytes(b"not a font at all")
    with pytest.raises(DatasetError, match="bad.ttf"):
        build_dataset("glyphs", tmp_path / "b", font=bad)


# --- silhouettes -------------------------------------------------------------------------


def write_sources(src: Path) -> None:
    src.mkdir()
    yy, xx = np.mgrid[:120, :80]
    blob = ((yy - 60) / 40) ** 2 + ((xx - 40) / 25) ** 2 < 1
    Image.fromarray(np.where(blob, 10, 250).astype(np.uint8)).save(src / "a_dark.png")
    rgba = np.zeros((120, 80, 4), np.uint8)
    rgba[..., 3] = np.where(blob, 255, 0)
    Image.fromarray(rgba, mode="RGBA").save(src / "b_alpha.png")
    (src / "b_alpha.txt").write_text("0.5 0.8333\n0 -1\n")  # bottom of the shape
    (src / "c_broken.png").write_bytes(b"\x89PNG broken")
    Image.new("L", (50, 50), 128).save(src / "d_flat.png")
    (src / "notes.md").write_text("not an image")


def test_silhouettes_from_dir_skip_bad_files(tmp_path):
    write_sources(tmp_path / "src")
    with pytest.warns(DatasetWarning) as record:
        files = build_dataset("silhouettes", tmp_path / "out", count=5, source_dir=tmp_path / "src")
    messages = [str(w.message) for w in record]
    assert any("c_broken.png" in m for m in messages)
    assert any("d_flat.png" in m for m in messages)
    assert len(files) == 5
    index = json.loads((tmp_path / "out" / "index.json").read_text())
    assert index["skipped"] == 2 and index["count"] == 5
    assert index["sources"][:3] == ["file a_dark.png", "file b_alpha.png", "skimage.data.horse"]
    assert index["sources"][3].startswith("procedural")
    targets = load_dataset(tmp_path / "out")
    # both source files hold the same ellipse: same fitted mask
    assert np.array_equal(targets[0].mask, targets[1].mask)
    # the sidecar's start (bottom center) follows the crop: bottom of the shape plus margin
    x, y, dx, dy = targets[1].start
    assert x == pytest.approx(0.5, abs=0.02) and y == pytest.approx(0.9, abs=0.03)
    assert (dx, dy) == pytest.approx((0, -1))


def test_silhouettes_from_dir_read_any_mode_and_skip_huge_images(tmp_path):
    """Issue #27: a LAB TIFF crashed `targets build --from` (finding 7), and a 8 x 60000 PNG
    of 200 bytes took gigabytes once framed in a square (finding 6). The runtime's one
    loader reads every mode and checks the size from the header first."""
    src = tmp_path / "src"
    src.mkdir()
    yy, xx = np.mgrid[:120, :80]
    blob = ((yy - 60) / 40) ** 2 + ((xx - 40) / 25) ** 2 < 1
    gray = Image.fromarray(np.where(blob, 10, 250).astype(np.uint8))
    gray.convert("RGB").convert("LAB").save(src / "a_lab.tif")
    gray.save(src / "c_gray.png")
    tall = np.full((60000, 8), 255, np.uint8)
    tall[:30000, 2:6] = 0
    Image.fromarray(tall).convert("1").save(src / "b_tall.png")
    with pytest.warns(DatasetWarning) as record:
        build_dataset("silhouettes", tmp_path / "out", count=2, source_dir=src)
    assert [str(w.message) for w in record] == [
        f"skipped cannot read target image {src / 'b_tall.png'}: the image is 8 x 60000 px; "
        "the limit is 8192 px a side and 33,554,432 px in all"
    ]
    index = json.loads((tmp_path / "out" / "index.json").read_text())
    assert index["sources"] == ["file a_lab.tif", "file c_gray.png"]
    lab, plain = load_dataset(tmp_path / "out")
    assert np.array_equal(lab.mask, plain.mask)


def test_silhouettes_default_has_horse_and_procedural(tmp_path):
    files = build_dataset("silhouettes", tmp_path)
    index = json.loads((tmp_path / "index.json").read_text())
    assert len(files) == 1 + 2 * len(SHAPE_KINDS)
    assert index["sources"][0] == "skimage.data.horse"
    for t in load_dataset(tmp_path):
        assert 0.05 < t.mask.mean() < 0.8 and t.mask[t.start_pixel()]
    with pytest.raises(DatasetError, match="does not exist"):
        build_dataset("silhouettes", tmp_path / "x", source_dir=tmp_path / "nope")


@pytest.mark.parametrize("kind", SHAPE_KINDS)
def test_procedural_silhouettes_are_one_shape(kind):
    t = procedural_silhouette(kind, rng(0))
    assert label(t.mask, connectivity=2).max() == 1
    assert t.mask[t.start_pixel()]


def test_fit_mask_moves_start_with_shape():
    m = np.zeros((100, 200), bool)
    m[50:90, 20:60] = True  # 40 x 40 square in the lower left
    fitted, start = fit_mask(m, 50, margin=0.1, start=(40 / 200, 1.0, 0, -1))
    rows, cols = np.nonzero(fitted)
    assert rows.min() == 5 and rows.max() == 44 and cols.min() == 5 and cols.max() == 44
    assert start[0] == pytest.approx(0.5) and start[1] == pytest.approx(1.0, abs=0.11)


# --- builds ------------------------------------------------------------------------------


def test_build_writes_files_index_and_mirrors(tmp_path):
    files = build_dataset("scribbles", tmp_path, count=4, seed=5, mirror=True)
    names = [p.name for p in files]
    assert names == [
        "scribbles_0000.png",
        "scribbles_0000_m.png",
        "scribbles_0001.png",
        "scribbles_0001_m.png",
        "scribbles_0002.png",
        "scribbles_0002_m.png",
        "scribbles_0003.png",
        "scribbles_0003_m.png",
    ]
    for p in files:
        assert p.with_suffix(".txt").is_file()
    index = json.loads((tmp_path / "index.json").read_text())
    assert {k: index[k] for k in ("name", "count", "size", "seed", "complete")} == {
        "name": "scribbles",
        "count": 8,
        "size": 50,
        "seed": 5,
        "complete": True,
    }
    assert "synthetic" in index["source"]
    a, am = load_target(files[0]), load_target(files[1])
    assert np.array_equal(am.mask, a.mask[:, ::-1])
    assert am.start == pytest.approx(
        (1 - a.start[0], a.start[1], -a.start[2], a.start[3]), abs=1e-5
    )
    # the exact start of the generator survives the sidecar
    assert a.start == pytest.approx(scribble(rng(0, seed=5)).start, abs=1e-5)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_build_resumes_and_keeps_existing_files(tmp_path):
    build_dataset("scribbles", tmp_path, count=3)
    first = (tmp_path / "scribbles_0001.png").read_bytes()
    (tmp_path / "scribbles_0001.png").unlink()
    kept = tmp_path / "scribbles_0000.txt"
    kept.write_text("0.5 0.5\n0 -1\n")  # a user's edit is not overwritten on resume
    files = build_dataset("scribbles", tmp_path, count=5)
    assert len(files) == 5
    assert (tmp_path / "scribbles_0001.png").read_bytes() == first
    assert kept.read_text() == "0.5 0.5\n0 -1\n"
    with pytest.raises(DatasetError, match="other settings"):
        build_dataset("scribbles", tmp_path, count=5, seed=1)


def test_interrupted_build_keeps_finished_files(tmp_path, monkeypatch):
    spec = datasets.DATASETS["scribbles"]

    def flaky(count, seed, size, **_):
        for i, item in enumerate(spec.builder(count=count, seed=seed, size=size)):
            if i == 3:
                raise KeyboardInterrupt
            yield item

    monkeypatch.setitem(
        datasets.DATASETS,
        "scribbles",
        datasets.DatasetSpec("scribbles", spec.description, 300, flaky),
    )
    with pytest.raises(KeyboardInterrupt):
        build_dataset("scribbles", tmp_path, count=6)
    done = sorted(p.name for p in tmp_path.glob("*.png"))
    assert done == ["scribbles_0000.png", "scribbles_0001.png", "scribbles_0002.png"]
    assert json.loads((tmp_path / "index.json").read_text())["complete"] is False
    with pytest.raises(TargetError, match="incomplete"):
        load_dataset(tmp_path)
    monkeypatch.setitem(datasets.DATASETS, "scribbles", spec)
    assert len(build_dataset("scribbles", tmp_path, count=6)) == 6


def test_build_rejects_bad_arguments(tmp_path):
    with pytest.raises(DatasetError, match="unknown dataset"):
        build_dataset("doodles", tmp_path)
    with pytest.raises(DatasetError, match="count"):
        build_dataset("scribbles", tmp_path, count=-1)
    with pytest.raises(DatasetError, match="size"):
        build_dataset("scribbles", tmp_path, size=4)


def test_other_working_size(tmp_path):
    files = build_dataset("glyphs", tmp_path, count=2, size=32)
    assert Image.open(files[0]).size == (32, 32)
    assert load_dataset(tmp_path)[0].mask.shape == (32, 32)


# --- contact sheets ----------------------------------------------------------------------


def test_contact_sheet(tmp_path):
    targets = [scribble(rng(i)) for i in range(7)]
    path = contact_sheet(targets, tmp_path / "sheet.png", cols=4, cell=40)
    img = Image.open(path)
    assert img.size == (4 * 44 + 4, 2 * (44 + 12) + 4)
    rgb = np.asarray(img.convert("RGB")).astype(int)
    red = (rgb[..., 0] > 180) & (rgb[..., 1] < 80)
    assert red.sum() > 7 * 10  # one arrow per target
    assert os.path.getsize(path) < 200_000
    with pytest.raises(DatasetError):
        contact_sheet([], tmp_path / "none.png")


def test_targets_with_names_survive_build(tmp_path):
    files = build_dataset("silhouettes", tmp_path, count=2)
    t = load_target(files[0])
    assert isinstance(t, Target) and t.name == "silhouettes_0000"
