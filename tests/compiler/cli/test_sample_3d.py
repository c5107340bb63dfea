"""`ngpmc sample` of a 3D grammar (meshes, pictures) and the 2D outputs left as they were.
Until the 3D language lands, a 3D program is the vines program marked `dim = 3` whose
forward sample is a hand-made list of 3D primitives."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image
from repo_paths import REPO

from ngpm_compiler.cli import grammar as grammar_cli
from ngpm_compiler.cli import main

trimesh = pytest.importorskip("trimesh")

VINES = REPO / "grammars" / "vines.lsys"
PRIMS = [("seg3", 0, 0, 0, 0, 1, 0, 0.2, 0), ("seg3", 0, 1, 0, 0.3, 2, 0, 0.15, 0),
         ("leaf3", 0.3, 2, 0, 0, 1, 0, 1, 0, 0, 0.6, 0.3, 0), ("sphere", 0, 2.2, 0, 0.1, 0)]


@pytest.fixture
def three_d(monkeypatch: pytest.MonkeyPatch) -> None:
    import ngpm_runtime.inference.smc as smc

    real_load = grammar_cli.load

    def load(path: str):
        compiled = real_load(path)
        program = compiled.program()
        program.dim = 3
        return SimpleNamespace(program=lambda: program)

    def forward(program, seed=0, start=None, max_modules=None):
        return SimpleNamespace(primitives=list(PRIMS), log_prior=-1.5, status="done",
                               limit=None)

    monkeypatch.setattr(grammar_cli, "load", load)
    monkeypatch.setattr(smc, "forward", forward)


@pytest.mark.parametrize("suffix", [".glb", ".obj", ".ply"])
def test_sample_writes_a_mesh(three_d: None, tmp_path: Path, suffix: str,
                              capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / f"tree{suffix}"
    assert main(["sample", str(VINES), "-o", str(out)]) == 0
    loaded = trimesh.load(out, process=False)
    geoms = list(loaded.geometry.values()) if hasattr(loaded, "geometry") else [loaded]
    assert sum(len(g.faces) for g in geoms) > 100
    assert np.allclose(loaded.bounds[:, 1], [0, 2.6], atol=1e-5)  # the leaf reaches 2 + 0.6
    line = capsys.readouterr().out
    assert "4 primitives" in line and "triangles" in line and str(out) in line


def test_sample_png_and_gif_of_a_3d_grammar(three_d: None, tmp_path: Path) -> None:
    args = ["sample", str(VINES), "-o", str(tmp_path / "t.glb"), "--png", str(tmp_path / "p.png"),
            "--gif", str(tmp_path / "t.gif"), "--view", "30,10", "--size", "64"]
    assert main(args) == 0
    with Image.open(tmp_path / "p.png") as pic:
        assert pic.size == (64, 64)
    with Image.open(tmp_path / "t.gif") as pic:
        assert pic.size == (32, 32) and pic.n_frames == 24
    assert main(["sample", str(VINES), "-o", str(tmp_path / "o.png"), "--size", "48"]) == 0
    with Image.open(tmp_path / "o.png") as pic:
        assert pic.size == (48, 48)
    assert (tmp_path / "t.glb").is_file()


def test_svg_of_a_3d_grammar_is_refused(three_d: None, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sample", str(VINES), "-o", str(tmp_path / "t.svg")]) == 1
    assert "SVG output is for 2D grammars" in capsys.readouterr().err


@pytest.mark.parametrize("extra", [["-o", "t.glb"], ["-o", "t.ply"],
                                   ["-o", "t.png", "--gif", "t.gif"],
                                   ["-o", "t.png", "--view", "0,0"]])
def test_mesh_options_of_a_2d_grammar_are_one_line_errors(
        tmp_path: Path, extra: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    extra = [str(tmp_path / x) if x.startswith("t.") else x for x in extra]
    assert main(["sample", str(VINES), *extra]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "for 3D grammars" in err and "is 2D" in err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("bad", ["45", "a,b", "0,91", "nan,0"])
def test_view_is_checked(bad: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["sample", str(VINES), "-o", "x.png", "--view", bad])
    assert exit_.value.code == 2 and "--view" in capsys.readouterr().err


@pytest.mark.parametrize("suffix", [".png", ".svg"])
def test_2d_pictures_are_those_of_save_render(tmp_path: Path, suffix: str) -> None:
    from ngpm_runtime.image.render import save_render
    from ngpm_runtime.inference.smc import forward

    out = tmp_path / f"cli{suffix}"
    assert main(["sample", str(VINES), "--seed", "4", "-o", str(out), "--size", "96"]) == 0
    program = grammar_cli.load(str(VINES)).program()
    ref = save_render(list(forward(program, seed=4).primitives), tmp_path / f"ref{suffix}",
                      viewport=program.viewport, size=96)
    assert out.read_bytes() == ref.read_bytes()
