"""The `envelopes` set: filled silhouettes of a grammar's own forward samples (seeded,
varied, with enough ink and the grammar's start pose, resumable), and `ngpmc targets build
envelopes --grammar`."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from fixtures.grammars import SPECK
from ngpm_runtime.image.targets import load_dataset, read_sidecar
from repo_paths import REPO

from ngpm_compiler.cli import main
from ngpm_compiler.datasets.build import build_dataset
from ngpm_compiler.datasets.common import DatasetError
from ngpm_compiler.datasets.envelopes import MIN_INK, close, start_of
from ngpm_compiler.language.compile import load_grammar

BUSH = str(REPO / "grammars" / "bush.lsys")


def masks(directory) -> list[np.ndarray]:
    return [t.mask for t in load_dataset(directory, size=50)]


def test_closing_fills_gaps_and_keeps_every_pixel():
    mask = np.zeros((20, 20), bool)
    mask[2:18, 3:6] = mask[2:18, 8:11] = True  # two bars 2 px apart, the first at the border
    mask[0:4, 0] = True
    closed = close(mask, 2)
    assert closed[mask].all()  # closing only adds
    assert closed[5:15, 6:8].all()  # the gap between the bars is filled
    assert not closed[10, 15:].any()  # far from the ink nothing is added


def test_envelopes_are_seeded_varied_inked_and_start_at_the_grammar_start(tmp_path):
    files = build_dataset("envelopes", tmp_path / "a", count=8, seed=3, grammar=BUSH)
    again = build_dataset("envelopes", tmp_path / "b", count=8, seed=3, grammar=BUSH)
    assert [p.read_bytes() for p in files] == [p.read_bytes() for p in again]
    other = build_dataset("envelopes", tmp_path / "c", count=8, seed=4, grammar=BUSH)
    assert {p.read_bytes() for p in files}.isdisjoint(p.read_bytes() for p in other)
    ms = masks(tmp_path / "a")
    assert len({m.tobytes() for m in ms}) == 8  # every sample its own shape
    assert all(m.mean() >= MIN_INK for m in ms)
    # bush.lsys: viewport -7 7 -1 13, start (0, 0) heading up
    assert start_of(load_grammar(BUSH)) == pytest.approx((0.5, 13 / 14, 0.0, -1.0))
    start = read_sidecar(files[0].with_suffix(".txt"))
    assert start == pytest.approx((0.5, 13 / 14, 0.0, -1.0), abs=1e-6)
    index = json.loads((tmp_path / "a" / "index.json").read_text())
    assert index["grammar"] == "bush.lsys" and len(index["grammar_sha"]) == 64
    assert "envelope 0 (sample 0.0, " in index["sources"][0]


def test_envelopes_fill_the_drawing(tmp_path):
    """An envelope holds the sample's drawing and more (its gaps closed)."""
    from ngpm_runtime.image.raster import rasterize
    from ngpm_runtime.inference.smc import SMCOptions, smc

    from ngpm_compiler.datasets.envelopes import envelope

    program = load_grammar(BUSH)
    res = smc(program, None, 4, options=SMCOptions(seed=1, ess_threshold=0.5))
    for p in res.particles:
        img = rasterize(list(p.primitives), program.viewport, 50, 50) > 0
        env = envelope(list(p.primitives), program, 50)
        assert env[img].all() and env.sum() > img.sum()


def test_an_interrupted_build_resumes_and_another_grammar_is_refused(tmp_path):
    out = tmp_path / "env"
    files = build_dataset("envelopes", out, count=5, seed=0, grammar=BUSH)
    before = [p.read_bytes() for p in files]
    files[2].unlink()
    files[4].with_suffix(".txt").unlink()
    again = build_dataset("envelopes", out, count=5, seed=0, grammar=BUSH)
    assert [p.read_bytes() for p in again] == before
    edited = tmp_path / "bush.lsys"
    edited.write_text(open(BUSH).read().replace("#define FORK 30", "#define FORK 40"))
    with pytest.raises(DatasetError, match="other settings .*grammar_sha"):
        build_dataset("envelopes", out, count=5, seed=0, grammar=edited)


def test_a_grammar_that_draws_too_little_is_one_error(tmp_path):
    speck = tmp_path / "speck.lsys"
    speck.write_text(SPECK)
    with pytest.raises(DatasetError, match="forward samples drew too little"):
        build_dataset("envelopes", tmp_path / "e", count=3, grammar=speck)
    with pytest.raises(DatasetError, match="give --grammar FILE"):
        build_dataset("envelopes", tmp_path / "f", count=3)
    with pytest.raises(DatasetError, match="3D grammar"):
        build_dataset("envelopes", tmp_path / "g", count=3, grammar=REPO / "grammars/tree3d.lsys")


def test_cli_builds_envelopes_of_a_grammar(tmp_path, capsys):
    out = tmp_path / "env"
    argv = ["targets", "build", "envelopes", "--grammar", BUSH, "-o", str(out), "--count", "4"]
    assert main([*argv, "--seed", "7", "--mirror"]) == 0
    assert "envelopes: 8 targets in" in capsys.readouterr().out
    mirrored = read_sidecar(out / "envelopes_0000_m.txt")
    assert mirrored[0] == pytest.approx(0.5) and math.isclose(mirrored[3], -1.0)
    assert main(["targets", "build", "envelopes", "-o", str(tmp_path / "x")]) != 0
    assert "give --grammar FILE" in capsys.readouterr().err
    assert main(["targets", "build", "varied", "--grammar", BUSH, "-o", str(tmp_path / "y")])
    assert "--grammar is for the envelopes set" in capsys.readouterr().err
