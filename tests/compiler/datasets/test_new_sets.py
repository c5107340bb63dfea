"""The varied and shapes training targets, clip-art silhouettes and script-font held-out glyphs."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from ngpm_runtime.image.morphology import label
from ngpm_runtime.image.targets import load_dataset
from PIL import Image, ImageDraw

from ngpm_compiler.datasets.build import build_dataset
from ngpm_compiler.datasets.clipart import clipart_reject
from ngpm_compiler.datasets.varied import MAX_WIDTH_PX, MIN_WIDTH_PX, VARIED_KINDS, varied

SCRIPT_FONT = Path("/usr/share/fonts/opentype/urw-base35/Z003-MediumItalic.otf")
CLIPART = Path("/usr/share/openclipart/svg/animals/mammals")


def test_varied_targets_keep_their_promises():
    seen = set()
    for i in range(60):
        t, info = varied(np.random.default_rng([0, 7, i]))
        seen.add(info["kind"])
        assert all(MIN_WIDTH_PX <= w <= MAX_WIDTH_PX for w in info["widths"])
        if info["kind"] == "script":
            assert max(info["widths"]) <= 2.2
        assert int(label(t.mask).max()) == info["parts"]
        assert (info["parts"] >= 2) == (info["kind"] == "parts")
        assert t.mask[t.start_pixel()]
        assert 0.02 <= t.mask.mean() <= 0.45
    assert seen == set(VARIED_KINDS)
    widths = [w for i in range(60) for w in varied(np.random.default_rng([0, 7, i]))[1]["widths"]]
    assert min(widths) < 1.5 and max(widths) > 5.0  # the whole 1-6 px range is used
    again, _ = varied(np.random.default_rng([0, 7, 5]))
    assert np.array_equal(again.mask, varied(np.random.default_rng([0, 7, 5]))[0].mask)


def test_varied_dataset_builds(tmp_path):
    files = build_dataset("varied", tmp_path / "v", count=4, mirror=True)
    assert len(files) == 8 and len(load_dataset(tmp_path / "v")) == 8


def test_shapes_are_the_procedural_silhouettes_without_the_horse(tmp_path):
    build_dataset("shapes", tmp_path / "s", count=3, seed=5)
    build_dataset("silhouettes", tmp_path / "sil", count=4, seed=5)
    shapes, sil = load_dataset(tmp_path / "s"), load_dataset(tmp_path / "sil")
    assert len(shapes) == 3 and len(sil) == 4
    for a, b in zip(shapes, sil[1:], strict=True):  # silhouettes: the horse first
        assert np.array_equal(a.mask, b.mask)
    build_dataset("shapes", tmp_path / "s6", count=3, seed=6)
    assert not np.array_equal(load_dataset(tmp_path / "s6")[0].mask, shapes[0].mask)


def test_clipart_reject():
    square = np.zeros((50, 50), bool)
    square[10:40, 10:40] = True
    assert "bounding box" in clipart_reject(square)
    assert "canvas" in clipart_reject(np.zeros((50, 50), bool) | (np.arange(50) < 1))
    two = np.zeros((50, 50), bool)
    two[5:25, 5:12] = two[5:25, 30:37] = True
    assert clipart_reject(two) == "in several large parts"
    shape = np.zeros((50, 50), bool)
    shape[10:40, 20:25] = shape[10:15, 10:40] = True
    assert clipart_reject(shape) is None


def test_clipart_from_png_folder(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    for i in range(3):
        img = Image.new("RGBA", (120, 120), (0, 0, 0, 0))
        d = ImageDraw.Draw(img)
        d.ellipse((20, 30 + i * 5, 100, 70), fill=(200, 30, 30, 255))
        d.rectangle((30, 60, 40, 110), fill=(0, 0, 0, 255))
        img.save(src / f"animal_{i}.png")
    files = build_dataset("clipart", tmp_path / "c", source_dir=src)
    ts = load_dataset(tmp_path / "c")
    assert len(files) == len(ts) == 3 and all(t.mask.mean() > 0.08 for t in ts)


@pytest.mark.skipif(
    not CLIPART.is_dir() or shutil.which("rsvg-convert") is None,
    reason="Debian packages openclipart-svg and librsvg2-bin not installed",
)
def test_clipart_from_openclipart_svgs(tmp_path):
    files = build_dataset("clipart", tmp_path / "c", count=3, source_dir=CLIPART)
    assert len(files) == 3
    assert all(clipart_reject(t.mask) is None for t in load_dataset(tmp_path / "c"))


@pytest.mark.skipif(
    not SCRIPT_FONT.is_file(), reason="script font not installed (Debian package fonts-urw-base35)"
)
def test_script_glyphs_are_thin(tmp_path):
    build_dataset("glyphs", tmp_path / "g", count=20, font=SCRIPT_FONT)
    ts = load_dataset(tmp_path / "g")
    assert len(ts) == 20 and np.mean([t.mask.mean() for t in ts]) < 0.12
