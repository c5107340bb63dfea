"""Tests for ngpm_runtime.image.targets: formats, resizing, sidecars, mirroring, auto start."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from ngpm_runtime.errors import NgpmError, TargetError
from ngpm_runtime.image.targets import (
    MAX_FRAMES,
    ImageDecodeError,
    ImageFormatError,
    ImageSizeError,
    Target,
    auto_start,
    image_to_mask,
    load_dataset,
    load_target,
    read_image,
    read_sidecar,
    resize_mask,
    save_target,
    write_sidecar,
)
from PIL import Image, ImageDraw, ImageFile


def disk_mask(h: int = 100, w: int = 100, cy: float = 50, cx: float = 50, r: float = 25):
    yy, xx = np.mgrid[:h, :w]
    return (yy - cy) ** 2 + (xx - cx) ** 2 < r * r


def save_gray(path: Path, mask: np.ndarray, fg: int = 0, bg: int = 255) -> Path:
    Image.fromarray(np.where(mask, fg, bg).astype(np.uint8), mode="L").save(path)
    return path


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


# --- Target, start pose, mirroring -------------------------------------------------------


def test_start_pose_maps_viewport_and_heading():
    t = Target(np.ones((4, 4), bool) & (np.arange(4) < 2), (0.25, 0.75, 0.0, -1.0), "t")
    x, y, heading = t.start_pose((-12, 12, -22, 2))
    assert x == pytest.approx(-12 + 0.25 * 24)
    assert y == pytest.approx(2 - 0.75 * 24)
    assert heading == pytest.approx(90.0)
    right = Target(t.mask, (0.5, 0.5, 1.0, 0.0)).start_pose((0, 1, 0, 1))
    assert right == pytest.approx((0.5, 0.5, 0.0))
    down_left = Target(t.mask, (0.0, 0.0, -1.0, 1.0)).start_pose((0, 1, 0, 1))
    assert down_left == pytest.approx((0.0, 1.0, -135.0))


def test_target_normalizes_direction_and_rejects_bad_starts():
    m = np.zeros((10, 10), bool)
    t = Target(m, (0.5, 0.5, 0.0, -3.0))
    assert t.start == pytest.approx((0.5, 0.5, 0.0, -1.0))
    for bad in [(1.5, 0.5, 0, 1), (0.5, -0.2, 0, 1), (0.5, 0.5, 0, 0), (0.5, math.nan, 0, 1)]:
        with pytest.raises(TargetError):
            Target(m, bad)
    with pytest.raises(TargetError):
        Target(np.zeros((2, 2, 2), bool), (0.5, 0.5, 0, 1))


def test_mirror_flips_mask_and_annotation():
    m = np.zeros((20, 30), bool)
    m[5:15, 2:6] = True
    t = Target(m, (0.11, 0.7, 0.6, -0.8), "a")
    mt = t.mirrored()
    assert mt.name == "a_m"
    assert np.array_equal(mt.mask, m[:, ::-1])
    assert mt.start == pytest.approx((0.89, 0.7, -0.6, -0.8))
    # the start pixel moves to the mirrored column
    r, c = t.start_pixel()
    assert mt.start_pixel() == (r, 30 - 1 - c)
    back = mt.mirrored()
    assert np.array_equal(back.mask, m)
    assert back.start == pytest.approx(t.start)
    # world heading is reflected about the vertical
    h = t.start_pose((0, 1, 0, 1))[2]
    assert mt.start_pose((0, 1, 0, 1))[2] == pytest.approx(180 - h)


# --- format detection --------------------------------------------------------------------


def test_dark_on_light_and_light_on_dark(tmp_path):
    m = disk_mask()
    a = load_target(save_gray(tmp_path / "dark.png", m, 0, 255), size=100)
    b = load_target(save_gray(tmp_path / "light.png", m, 255, 0), size=100)
    assert np.array_equal(a.mask, m)
    assert np.array_equal(b.mask, m)


def test_border_rule_beats_minority(tmp_path):
    # a big dark shape covering most of the image, light border: dark is the shape
    m = np.zeros((100, 100), bool)
    m[3:97, 3:97] = True
    m[40:60, 40:60] = False
    assert m.mean() > 0.5
    t = load_target(save_gray(tmp_path / "big.png", m), size=100)
    assert np.array_equal(t.mask, m)


def test_minority_rule_when_border_is_split(tmp_path):
    # left half of the border dark, right half light: the smaller class is the shape
    img = np.full((100, 100), 255, np.uint8)
    img[:, :50] = 0
    shape = disk_mask(r=15, cx=75)
    img[shape] = 0
    img[disk_mask(r=10, cx=25)] = 255
    path = tmp_path / "split.png"
    Image.fromarray(img).save(path)
    mask = image_to_mask(Image.open(path))
    assert np.array_equal(mask, img == 255)  # light pixels are the minority


def test_rgba_alpha_and_flat_alpha(tmp_path):
    m = disk_mask()
    rgba = np.zeros((100, 100, 4), np.uint8)  # black everywhere; only alpha holds the shape
    rgba[..., 3] = np.where(m, 255, 0)
    Image.fromarray(rgba, mode="RGBA").save(tmp_path / "alpha.png")
    assert np.array_equal(load_target(tmp_path / "alpha.png", size=100).mask, m)
    # opaque RGBA: alpha is flat, so gray levels decide
    rgba[..., 3] = 255
    rgba[..., :3] = np.where(m, 20, 230)[..., None]
    Image.fromarray(rgba, mode="RGBA").save(tmp_path / "opaque.png")
    assert np.array_equal(load_target(tmp_path / "opaque.png", size=100).mask, m)
    with pytest.raises(TargetError, match="alpha"):
        load_target(tmp_path / "opaque.png", polarity="alpha")


def test_jpeg_rgb_and_explicit_polarity(tmp_path):
    m = disk_mask()
    rgb = np.where(m[..., None], [30, 40, 120], [250, 245, 240]).astype(np.uint8)
    Image.fromarray(rgb).save(tmp_path / "shape.jpg", quality=85)
    t = load_target(tmp_path / "shape.jpg", size=100)
    assert iou(t.mask, m) > 0.97
    inv = load_target(tmp_path / "shape.jpg", size=100, polarity="light")
    assert iou(inv.mask, ~m) > 0.97
    dark = load_target(tmp_path / "shape.jpg", size=100, polarity="dark")
    assert iou(dark.mask, m) > 0.97
    with pytest.raises(TargetError, match="polarity"):
        load_target(tmp_path / "shape.jpg", polarity="sideways")


def test_palette_png_with_transparency(tmp_path):
    m = disk_mask()
    img = Image.fromarray(np.where(m, 1, 0).astype(np.uint8), mode="P")
    img.putpalette([255, 255, 255, 200, 0, 0] + [0] * 762)
    img.info["transparency"] = 0
    img.save(tmp_path / "pal.png", transparency=0)
    assert np.array_equal(load_target(tmp_path / "pal.png", size=100).mask, m)


# --- every PIL mode, sizes, animations (issue #27) ----------------------------------------


def colored_disk() -> Image.Image:
    """A dark blue disk on an off-white background, 96 x 64 px."""
    img = Image.new("RGB", (96, 64), (250, 245, 235))
    ImageDraw.Draw(img).ellipse((28, 12, 68, 52), fill=(20, 30, 110))
    return img


def in_mode(base: Image.Image, mode: str) -> Image.Image:
    """`base` in PIL mode `mode` (16-bit modes: the gray levels scaled to 0..65535)."""
    if mode.startswith("I;16"):
        order = {"I;16B": ">u2"}.get(mode, "<u2" if mode != "I;16N" else "=u2")
        levels = np.asarray(base.convert("L"), np.uint16) * 257
        return Image.frombytes(mode, base.size, levels.astype(order).tobytes())
    if mode in ("La", "RGBa"):
        return base.convert("RGBA").convert(mode)
    if mode == "PA":
        return base.convert("P").convert("PA")
    if mode == "1":
        return base.convert("1", dither=Image.Dither.NONE)
    return base.convert(mode)


@pytest.mark.parametrize("mode", Image.MODES)
def test_every_pil_mode_gives_the_shape(tmp_path, mode):
    """Finding 7: a TIFF in LAB mode raised a ValueError traceback. Each mode PIL can write
    (as TIFF, else PNG) is loaded from a file, the others are read in memory."""
    base = colored_disk()
    want = image_to_mask(base)
    img = in_mode(base, mode)
    for fmt in ("TIFF", "PNG"):
        path = tmp_path / f"shape.{fmt.lower()}"
        try:
            img.save(path, format=fmt)
        except (OSError, ValueError, KeyError):
            continue
        got = load_target(path, size=None).mask[16:80]  # unpad the 96 x 96 square
        break
    else:
        got = image_to_mask(img, name="in memory")
    assert iou(got, want) > 0.98, mode


def test_lab_tiff_loads_like_its_rgb(tmp_path):
    base = colored_disk()
    base.convert("LAB").save(tmp_path / "lab.tif")
    base.save(tmp_path / "rgb.png")
    lab = load_target(tmp_path / "lab.tif")
    assert np.array_equal(lab.mask, load_target(tmp_path / "rgb.png").mask)


def test_float_image_with_nan_and_infinity(tmp_path):
    values = np.where(image_to_mask(colored_disk()), 0.0, 1.0).astype(np.float32)
    values[0, :5] = [np.nan, np.inf, -np.inf, np.nan, np.nan]
    Image.fromarray(values, mode="F").save(tmp_path / "f.tif")
    mask = load_target(tmp_path / "f.tif", size=None).mask[16:80]
    assert iou(mask, image_to_mask(colored_disk())) > 0.98


def tall_png(path: Path) -> Path:
    """A 8 x 60000 px two-color PNG of a few hundred bytes."""
    pixels = np.full((60000, 8), 255, np.uint8)
    pixels[:30000, 2:6] = 0
    Image.fromarray(pixels).convert("1").save(path)
    return path


def test_image_size_is_checked_from_the_header_before_decoding(tmp_path, monkeypatch):
    """Finding 6: a 8 x 60000 PNG of 200 bytes was padded to a 60000 x 60000 square
    (3.35 GiB). Each side (so the padded square) and the pixel count are limited, and
    checked from the header: no pixel is decoded."""
    path = tall_png(tmp_path / "tall.png")
    assert path.stat().st_size < 2000

    def no_decoding(self):
        raise AssertionError("decoded")

    with monkeypatch.context() as patch:
        patch.setattr(ImageFile.ImageFile, "load", no_decoding)
        with pytest.raises(ImageSizeError) as info:
            load_target(path)
    text = str(info.value)
    assert "tall.png" in text and "8 x 60000 px" in text and "limit is 8192 px a side" in text
    wide = save_gray(tmp_path / "wide.png", disk_mask(100, 300, cx=150))
    with pytest.raises(ImageSizeError, match="the limit is 200 px a side"):
        read_image(wide, max_side=200)
    with pytest.raises(ImageSizeError, match="29,999 px in all"):
        read_image(wide, max_pixels=29_999)
    assert read_image(wide, max_side=300, max_pixels=30_000).size == (300, 100)


def test_only_the_listed_formats_are_read(tmp_path):
    colored_disk().save(tmp_path / "disk.ppm")
    with pytest.raises(ImageFormatError, match="PPM images are not accepted"):
        load_target(tmp_path / "disk.ppm")
    (tmp_path / "text.png").write_text("not an image")
    with pytest.raises(ImageFormatError, match="not an image"):
        load_target(tmp_path / "text.png")
    colored_disk().save(tmp_path / "cut.png")
    (tmp_path / "cut.png").write_bytes((tmp_path / "cut.png").read_bytes()[:300])
    with pytest.raises(ImageDecodeError, match="cannot decode target image .*cut.png"):
        load_target(tmp_path / "cut.png")


def test_animation_frames_searched_and_checked_are_bounded(tmp_path):
    blank = Image.new("RGB", (64, 64), "white")
    flat = [Image.new("RGB", (64, 64), (240 + k % 2 * 10,) * 3) for k in range(MAX_FRAMES + 5)]
    flat[0].save(tmp_path / "blank.gif", save_all=True, append_images=flat[1:], duration=50)
    with pytest.raises(TargetError, match=f"none of the animation's first {MAX_FRAMES} "):
        read_image(tmp_path / "blank.gif")
    # a TIFF's pages each have their own size: a big second page is refused unread
    blank.save(
        tmp_path / "pages.tif", save_all=True, append_images=[Image.new("RGB", (300, 40), "white")]
    )
    with pytest.raises(ImageSizeError, match="300 x 40 px; the limit is 200"):
        read_image(tmp_path / "pages.tif", max_side=200)
    # a multi-page TIFF gives its first page that holds a shape, in any mode
    blank.save(tmp_path / "lab.tif", save_all=True, append_images=[colored_disk().convert("LAB")])
    img = read_image(tmp_path / "lab.tif")
    assert img.info["ngpm_frame"] == 1 and img.size == (96, 64)


# --- resizing ----------------------------------------------------------------------------


def test_resize_pads_to_square_keeping_aspect(tmp_path):
    m = np.zeros((100, 200), bool)  # wide image, shape fills a centered square
    m[25:75, 75:125] = True
    t = load_target(save_gray(tmp_path / "wide.png", m), size=50)
    assert t.mask.shape == (50, 50)
    # padded to 200 x 200: the 50-px square sits at rows/cols 75..125 -> 18.75..31.25 at 50
    rows, cols = np.nonzero(t.mask)
    assert (rows.min(), rows.max(), cols.min(), cols.max()) == (19, 30, 19, 30)
    assert not t.mask[:18].any() and not t.mask[32:].any()
    small = load_target(tmp_path / "wide.png", size=20)
    assert small.mask.shape == (20, 20)
    native = load_target(tmp_path / "wide.png", size=None)
    assert native.mask.shape == (200, 200)


def test_resize_mask_is_area_threshold():
    m = np.zeros((4, 4), bool)
    m[0, 0:2] = True  # top-left 2x2 block half covered -> foreground
    m[2, 2] = True  # bottom-right block quarter covered -> background
    assert resize_mask(m, 2).tolist() == [[True, False], [False, False]]
    big = resize_mask(np.eye(2, dtype=bool), 4)
    assert big.tolist() == [[1, 1, 0, 0], [1, 1, 0, 0], [0, 0, 1, 1], [0, 0, 1, 1]]


def test_sidecar_follows_padding(tmp_path):
    m = np.zeros((100, 200), bool)
    m[20:100, 90:110] = True
    save_gray(tmp_path / "bar.png", m)
    write_sidecar(tmp_path / "bar.txt", (0.5, 1.0, 0.0, -1.0))
    t = load_target(tmp_path / "bar.png", size=50)
    assert t.start == pytest.approx((0.5, 0.75, 0.0, -1.0))


# --- sidecars and saving -----------------------------------------------------------------


def test_save_load_round_trip(tmp_path):
    m = disk_mask(50, 50, 30, 20, 12)
    m[0:3, :] = True  # the shape touches the border: polarity still comes back right
    t = Target(m, (0.4, 0.8, 0.6, -0.8), "round")
    path = save_target(t, tmp_path / "sub" / "round.png")
    assert path.name == "round.png" and (tmp_path / "sub" / "round.txt").is_file()
    lines = (tmp_path / "sub" / "round.txt").read_text().splitlines()
    assert [len(ln.split()) for ln in lines] == [2, 2]
    back = load_target(path)
    assert np.array_equal(back.mask, m)
    assert back.start == pytest.approx(t.start, abs=1e-6)
    assert back.name == "round"
    assert sorted(p.name for p in (tmp_path / "sub").iterdir()) == ["round.png", "round.txt"]


def test_original_sidecar_format_is_read(tmp_path):
    (tmp_path / "s.txt").write_text("0.5 0.9\n0 -1\n")
    assert read_sidecar(tmp_path / "s.txt") == pytest.approx((0.5, 0.9, 0.0, -1.0))
    (tmp_path / "c.txt").write_text("0.25, 0.5\r\n3 4\r\n\r\n")
    assert read_sidecar(tmp_path / "c.txt") == pytest.approx((0.25, 0.5, 0.6, 0.8))


@pytest.mark.parametrize(
    "text",
    [
        "",
        "0.5 0.5\n",
        "0.5 0.5\n0 -1\n1 1\n",
        "0.5 0.5 0.5\n0 -1\n",
        "a b\n0 -1\n",
        "0.5 0.5\n0 0\n",
        "1.5 0.5\n0 -1\n",
        "nan 0.5\n0 -1\n",
    ],
)
def test_malformed_sidecar_names_file(tmp_path, text):
    m = disk_mask()
    save_gray(tmp_path / "img.png", m)
    (tmp_path / "img.txt").write_text(text)
    with pytest.raises(TargetError) as info:
        load_target(tmp_path / "img.png")
    msg = str(info.value)
    assert "img.txt" in msg and "\n" not in msg


# --- bad images --------------------------------------------------------------------------


def make_bad(tmp_path: Path, kind: str) -> Path:
    path = tmp_path / f"{kind}.png"
    if kind == "missing":
        return path
    if kind == "garbage":
        path.write_bytes(b"this is not a png")
    elif kind == "flat":
        Image.new("L", (64, 64), 200).save(path)
    elif kind == "tiny":
        Image.fromarray(np.eye(4, dtype=np.uint8) * 255).save(path)
    elif kind == "thin":  # a 1-px line in a big image vanishes at 50 x 50
        img = np.full((1000, 1000), 255, np.uint8)
        img[100:900, 500] = 0
        Image.fromarray(img).save(path)
    elif kind == "speck":
        img = np.full((100, 100), 255, np.uint8)
        img[50:52, 50:52] = 0
        Image.fromarray(img).save(path)
    return path


@pytest.mark.parametrize("kind", ["missing", "garbage", "flat", "tiny", "thin", "speck"])
def test_bad_images_raise_one_line_naming_file(tmp_path, kind):
    path = make_bad(tmp_path, kind)
    with pytest.raises(TargetError) as info:
        load_target(path)
    assert isinstance(info.value, NgpmError)
    assert path.name in str(info.value) and "\n" not in str(info.value)


def test_all_foreground_is_rejected(tmp_path):
    img = np.zeros((100, 100), np.uint8)
    img[0, :10] = 255  # almost all dark
    Image.fromarray(img).save(tmp_path / "full.png")
    with pytest.raises(TargetError, match="all foreground"):
        load_target(tmp_path / "full.png", polarity="dark")


# --- automatic start ---------------------------------------------------------------------


def test_auto_start_vertical_bar_starts_at_bottom_heading_up():
    m = np.zeros((50, 50), bool)
    m[10:40, 22:29] = True
    x, y, dx, dy = auto_start(m)
    assert x == pytest.approx(25.5 / 50, abs=0.03)
    assert y == pytest.approx(39.5 / 50, abs=0.03)
    assert dx == pytest.approx(0.0, abs=0.05) and dy == pytest.approx(-1.0, abs=0.01)


def test_auto_start_other_shapes():
    m = np.zeros((50, 50), bool)
    m[35:40, 5:45] = True
    m[10:40, 23:28] = True  # inverted T: the left end of its base (the lower ends), heading right
    x, y, dx, dy = auto_start(m)
    assert x < 0.15 and 0.7 < y < 0.8 and dx > 0.95
    d = disk_mask(50, 50, 25, 25, 10)  # a disk: bottom, straight up
    x, y, dx, dy = auto_start(d)
    assert abs(x - 0.5) < 0.04 and y > 0.65 and (dx, dy) == pytest.approx((0, -1))
    slanted = np.zeros((50, 50), bool)
    for r in range(10, 40):
        slanted[r, r - 5 : r] = True  # leans to the right going down
    x, y, dx, dy = auto_start(slanted)
    assert dy < 0 and dx < 0  # from the bottom-right end, up and to the left
    assert y > 0.7


def _ring(width: int, gap_rows: slice | None = None) -> np.ndarray:
    yy, xx = np.mgrid[0:50, 0:50]
    r = np.hypot(yy - 25, xx - 25)
    m = (r >= 15 - width / 2) & (r <= 15 + width / 2)
    if gap_rows is not None:
        m[gap_rows, 25:] = False  # open on the right: a C
    return m


def test_auto_start_prefers_a_stroke_end():
    # a C open on the right: start at its lower end (not mid-stroke at the bottom of the
    # arc), heading along the stroke, to the left
    x, y, dx, dy = auto_start(_ring(4, slice(20, 31)))
    assert x > 0.6 and 0.6 < y < 0.85 and dx < -0.5
    # a closed ring has no end: from its lowest point, along the bottom of the ring
    x, y, dx, dy = auto_start(_ring(4))
    assert y > 0.75 and abs(dx) > 0.95


def test_auto_start_is_inside_largest_component_and_deterministic():
    m = disk_mask(50, 50, 20, 15, 8) | disk_mask(50, 50, 40, 40, 3)
    s1, s2 = auto_start(m), auto_start(m.copy())
    assert s1 == s2
    t = Target(m, s1)
    r, c = t.start_pixel()
    assert m[r, c] and r < 30  # in the big disk, not the small lower one
    with pytest.raises(TargetError):
        auto_start(np.zeros((5, 5), bool))


def test_load_without_sidecar_uses_auto_start(tmp_path):
    m = np.zeros((100, 100), bool)
    m[20:80, 45:55] = True
    t = load_target(save_gray(tmp_path / "bar.png", m), size=50)
    assert t.start[3] < -0.95 and t.start[1] > 0.75


# --- datasets ----------------------------------------------------------------------------


def test_load_dataset_with_and_without_index(tmp_path):
    targets = [
        Target(disk_mask(50, 50, 25, 10 + 10 * i, 6), (0.5, 0.6, 0, -1), f"d_{i:04d}")
        for i in range(3)
    ]
    for t in targets:
        save_target(t, tmp_path / f"{t.name}.png")
    Image.new("L", (30, 30), 0).save(tmp_path / "no_sidecar.png")  # ignored without index
    got = load_dataset(tmp_path)
    assert [t.name for t in got] == ["d_0000", "d_0001", "d_0002"]
    assert all(np.array_equal(a.mask, b.mask) for a, b in zip(got, targets, strict=True))
    (tmp_path / "index.json").write_text(json.dumps({"files": ["d_0002.png", "d_0000.png"]}))
    assert [t.name for t in load_dataset(tmp_path)] == ["d_0002", "d_0000"]
    (tmp_path / "index.json").write_text("{not json")
    with pytest.raises(TargetError, match="index.json"):
        load_dataset(tmp_path)
    with pytest.raises(TargetError, match="does not exist"):
        load_dataset(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(TargetError, match="no targets"):
        load_dataset(tmp_path / "empty")


def test_sixteen_bit_png_and_numpy_size(tmp_path):
    m = disk_mask()
    Image.fromarray(np.where(m, 1000, 60000).astype(np.uint16)).save(tmp_path / "deep.png")
    t = load_target(tmp_path / "deep.png", size=np.int64(100))
    assert np.array_equal(t.mask, m)
    with pytest.raises(TargetError, match="size"):
        load_target(tmp_path / "deep.png", size=2.5)


def test_jpeg_exif_orientation_is_applied(tmp_path):
    m = np.zeros((60, 100), bool)  # stored wide with a bar on the left ...
    m[10:50, 5:25] = True
    img = Image.fromarray(np.where(m, 0, 255).astype(np.uint8))
    exif = Image.Exif()
    exif[0x0112] = 6  # ... shown rotated 90 degrees clockwise: bar at the top
    img.save(tmp_path / "photo.jpg", exif=exif, quality=95)
    t = load_target(tmp_path / "photo.jpg", size=100)
    rows, cols = np.nonzero(t.mask)
    assert rows.max() < 30 and 20 < cols.mean() < 80


def test_nearly_opaque_alpha_falls_back_to_gray(tmp_path):
    m = disk_mask()
    rgba = np.zeros((100, 100, 4), np.uint8)
    rgba[..., :3] = np.where(m, 0, 255)[..., None]
    rgba[..., 3] = 255
    rgba[:5, :5, 3] = 200  # alpha varies, but nothing is transparent
    Image.fromarray(rgba, mode="RGBA").save(tmp_path / "semi.png")
    assert np.array_equal(load_target(tmp_path / "semi.png", size=100).mask, m)


@settings(max_examples=60, deadline=None)
@given(x=st.floats(0, 1), y=st.floats(0, 1), a=st.floats(-math.pi, math.pi))
def test_start_pose_and_mirror_properties(x, y, a):
    t = Target(np.zeros((8, 8), bool), (x, y, math.cos(a), math.sin(a)))
    vp = (-12.0, 12.0, -22.0, 2.0)
    wx, wy, h = t.start_pose(vp)
    assert -12 <= wx <= 12 and -22 <= wy <= 2
    # heading points the same way as the image direction with y flipped
    assert math.cos(math.radians(h)) == pytest.approx(t.start[2], abs=1e-9)
    assert math.sin(math.radians(h)) == pytest.approx(-t.start[3], abs=1e-9)
    mx, my, _ = t.mirrored().start_pose(vp)
    assert mx == pytest.approx(-wx, abs=1e-9) and my == pytest.approx(wy)
