"""Package data, 3D: the bundled vines3d sampler is up to date with grammars/vines3d.lsys,
its guide belongs to it and was trained, and it is the default of a grow into a 3D target
(`ngpmc grow shape.obj -N 10 -o tree.glb` with no --grammar)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
from ngpm_runtime import bundled
from ngpm_runtime.errors import GuideError, ProgramError
from ngpm_runtime.inference.guide import Guide
from repo_paths import REPO

VINES3D = REPO / "grammars" / "vines3d.lsys"
MIN_TRACES = 300  # scripts/train_vines3d_guide.sh (ngpmc learn) records thousands


def vines3d_hash() -> str:
    text = VINES3D.read_text(encoding="utf-8").replace("\r\n", "\n")
    return "sha256:" + hashlib.sha256(text.encode("utf-8")).hexdigest()


def test_bundled_3d_sampler_is_up_to_date_with_vines3d_lsys() -> None:
    from ngpm_compiler.language.compile import compile_grammar

    program = bundled.bundled_program3d()
    assert program.name == "vines3d" and program.dim == 3
    assert program.grammar_hash == vines3d_hash(), (
        "runtime/ngpm_runtime/data/vines3d_sampler.py is stale: run "
        "`ngpmc compile grammars/vines3d.lsys -o runtime/ngpm_runtime/data`"
    )
    compiled = compile_grammar(VINES3D)
    shipped = json.loads((bundled.DATA_DIR / "vines3d_sites.json").read_text(encoding="utf-8"))
    assert shipped == compiled.sites_json()


def test_bundled_3d_guide_belongs_to_vines3d_and_was_trained() -> None:
    guide = bundled.bundled_guide3d()
    assert isinstance(guide, Guide)
    assert guide.meta["grammar_hash"] == vines3d_hash()
    assert guide.fallback_sites == []
    assert guide.training["traces"] >= MIN_TRACES, "a tiny development guide was bundled"
    assert "context" not in guide.feature_set


def test_default_guide_of_a_3d_program() -> None:
    from ngpm_compiler.language.compile import compile_grammar

    program = compile_grammar(VINES3D).program()
    assert bundled.default_guide(program).path == str(bundled.data_path(bundled.GUIDE_3D))
    other = compile_grammar(REPO / "grammars" / "stochastic_tree3d.lsys").program()
    assert bundled.default_guide(other) is None


def test_missing_3d_files_are_one_line_errors(tmp_path: Path, monkeypatch) -> None:
    program = bundled.bundled_program3d()
    monkeypatch.setattr(bundled, "DATA_DIR", tmp_path)
    with pytest.raises(GuideError, match="train_vines3d_guide.sh") as err:
        bundled.bundled_guide3d(program)
    assert "\n" not in str(err.value)
    with pytest.raises(ProgramError, match="bundled 3D sampler is missing"):
        bundled.bundled_program3d()


def test_grow_a_mesh_with_no_grammar_uses_the_bundled_3d_guide(tmp_path: Path, capsys) -> None:
    from fixtures.volume3d import box_target
    from ngpm_runtime.volume.raster import VoxelGrid

    from ngpm_compiler.cli import main

    target = tmp_path / "box.npz"
    grid = VoxelGrid((0.0, 0.0, 0.0), 1 / 16, (16, 16, 16))
    box_target(grid, (0.2, 0.0, 0.3), (0.8, 0.7, 0.7)).to_npz(target)
    assert main(["grow", str(target), "-N", "10", "-o", str(tmp_path / "tree.glb")]) == 0
    out = capsys.readouterr().out
    assert "10 particles (guided)" in out and "vines3d_guide.onnx" in out
    assert (tmp_path / "tree.glb").read_bytes()[:4] == b"glTF"
