"""Tests for `ngpmc targets build|list|show`."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from ngpm_compiler.cli import main


def test_list(capsys):
    assert main(["targets", "list"]) == 0
    out = capsys.readouterr().out
    for name in ("scribbles", "glyphs", "silhouettes"):
        assert name in out


def test_build_and_show(tmp_path, capsys):
    out_dir = tmp_path / "s"
    assert (
        main(
            [
                "targets",
                "build",
                "scribbles",
                "-o",
                str(out_dir),
                "--count",
                "3",
                "--seed",
                "2",
                "--size",
                "40",
                "--mirror",
            ]
        )
        == 0
    )
    assert "6 targets" in capsys.readouterr().out
    index = json.loads((out_dir / "index.json").read_text())
    assert index["count"] == 6 and index["size"] == 40 and index["seed"] == 2
    assert Image.open(out_dir / "scribbles_0002_m.png").size == (40, 40)
    sheet = tmp_path / "sheet.png"
    assert main(["targets", "show", str(out_dir), "-o", str(sheet), "--max", "4"]) == 0
    assert "4 of 6" in capsys.readouterr().out
    assert Image.open(sheet).size[0] > 4 * 40


def test_show_single_image(tmp_path):
    img = np.full((80, 60), 255, np.uint8)
    img[10:70, 25:35] = 0
    Image.fromarray(img).save(tmp_path / "bar.png")
    assert (
        main(["targets", "show", str(tmp_path / "bar.png"), "-o", str(tmp_path / "one.png")]) == 0
    )
    assert (tmp_path / "one.png").is_file()


def test_build_silhouettes_warns_about_bad_files(tmp_path, capsys):
    src = tmp_path / "src"
    src.mkdir()
    (src / "broken.png").write_bytes(b"nope")
    img = np.full((60, 60), 255, np.uint8)
    img[10:50, 20:40] = 0
    Image.fromarray(img).save(src / "good.png")
    assert (
        main(
            [
                "targets",
                "build",
                "silhouettes",
                "-o",
                str(tmp_path / "o"),
                "--count",
                "3",
                "--from",
                str(src),
            ]
        )
        == 0
    )
    cap = capsys.readouterr()
    assert "broken.png" in cap.err and "skipped 1" in cap.out
    assert len(list((tmp_path / "o").glob("silhouettes_*.png"))) == 3


def test_errors_are_one_line(tmp_path, capsys):
    rc = main(
        [
            "targets",
            "build",
            "glyphs",
            "-o",
            str(tmp_path / "g"),
            "--font",
            str(tmp_path / "missing.ttf"),
        ]
    )
    err = capsys.readouterr().err
    assert rc == 1 and err.startswith("ngpmc: error:") and err.count("\n") == 1
    assert "missing.ttf" in err
    rc = main(["targets", "show", str(tmp_path / "nothing.png"), "-o", str(tmp_path / "x.png")])
    err = capsys.readouterr().err
    assert rc == 1 and "nothing.png" in err and err.count("\n") == 1


def test_unknown_dataset_is_usage_error():
    with pytest.raises(SystemExit) as info:
        main(["targets", "build", "doodles", "-o", "x"])
    assert info.value.code == 2


def test_show_previews_at_the_working_size_and_warns(tmp_path, capsys):
    from fixtures.pictures import house

    picture = house(tmp_path / "house.png", 8)
    sheet = tmp_path / "sheet.png"
    assert main(["targets", "show", str(picture), "-o", str(sheet)]) == 0
    out = capsys.readouterr().out
    assert "warning: house: only" in out and "--size 128" in out
    assert main(["targets", "show", str(picture), "-o", str(sheet), "--size", "128"]) == 0
    assert "warning" not in capsys.readouterr().out
