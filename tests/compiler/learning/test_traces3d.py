"""The 3D learning pipeline through the CLI: `ngpmc traces` of a 3D grammar into a 3D
target set records the 3D feature rows (volume/features.py's layout, no context group),
`ngpmc train` and `ngpmc export` make a guide that Guide.load accepts for the 3D program
(and refuses with another layout), and `ngpmc grow` runs guided into a 3D target."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from ngpm_runtime.errors import GuideError, NgpmError
from ngpm_runtime.volume.features import check_guide_layouts, layout3d
from repo_paths import REPO

from ngpm_compiler.cli import main
from ngpm_compiler.language.compile import load_grammar
from ngpm_compiler.learning.trace_data import load_traces

TOPIARY = str(REPO / "grammars" / "topiary3d.lsys")


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 3D target set (3 blobs at 16^3), 4 traces, a model trained 2 epochs, its guide."""
    w = tmp_path_factory.mktemp("p3d")
    run = ["targets", "build", "blobs3d", "-o", str(w / "set"), "--count", "3"]
    assert main([*run, "--resolution", "16"]) == 0
    traces = ["traces", TOPIARY, "--targets", str(w / "set"), "-n", "4", "--particles", "4"]
    assert main([*traces, "-o", str(w / "traces"), "--workers", "1"]) == 0
    assert main(["train", str(w / "traces"), "-o", str(w / "m.pt"), "--epochs", "2"]) == 0
    assert main(["export", str(w / "m.pt"), "-o", str(w / "g.onnx")]) == 0
    return w


def test_traces_record_the_3d_feature_rows(pipeline: Path) -> None:
    program = load_grammar(TOPIARY)
    ts = load_traces(pipeline / "traces")
    assert len(ts.kept_jobs) == 4 and ts.data
    for site in program.sites:
        lay = layout3d(site)
        end = lay["partial"].stop
        assert ts.layouts[site.index] == {**lay, "context": slice(end, end)}  # empty in 3D
        if site.index in ts.data:
            assert ts.data[site.index].features.shape[1] == lay["partial"].stop
    assert all(np.isfinite(d.features).all() for d in ts.data.values())


def test_the_guide_loads_for_the_3d_program_and_grows(pipeline: Path, capsys) -> None:
    from ngpm_runtime.inference.guide import Guide

    program = load_grammar(TOPIARY)
    guide = Guide.load(pipeline / "g.onnx", program)
    assert guide.feature_set == "all" and guide.nets
    target = pipeline / "set" / "blobs3d_0000.npz"
    out = pipeline / "tree.glb"
    args = ["grow", str(target), "--grammar", TOPIARY, "--guide", str(pipeline / "g.onnx")]
    assert main([*args, "-N", "3", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "particles (guided)" in text and out.read_bytes()[:4] == b"glTF"


def test_check_guide_layouts_refuses_other_3d_features(pipeline: Path) -> None:
    from ngpm_runtime.inference.guide import Guide

    program = load_grammar(TOPIARY)
    meta = Guide.load(pipeline / "g.onnx", program).meta
    check_guide_layouts("g.onnx", meta, program)  # its own: accepted
    bad = json.loads(json.dumps(meta))
    first = next(iter(bad["features"]["layouts"]))
    bad["features"]["layouts"][first]["target"][1] -= 1
    with pytest.raises(GuideError, match="feature layout"):
        check_guide_layouts("g.onnx", bad, program)
    bad = json.loads(json.dumps(meta))
    bad["features"]["feature_set"] = "all+context"
    with pytest.raises(GuideError, match="context"):
        check_guide_layouts("g.onnx", bad, program)


def test_traces_of_a_3d_grammar_into_pictures_is_a_one_line_error(tmp_path: Path) -> None:
    from fixtures.datasets import make_dataset

    from ngpm_compiler.learning.traces import TraceConfig, generate_traces

    data = make_dataset(tmp_path / "pics")
    with pytest.raises(NgpmError, match="3D target set") as err:
        generate_traces(TraceConfig(TOPIARY, str(data), 2, 4, workers=1), tmp_path / "t", False)
    assert "\n" not in str(err.value)


def test_traces_sigma_is_recorded_in_the_key_and_is_3d_only(tmp_path: Path, pipeline: Path) -> None:
    from fixtures.datasets import make_dataset

    from ngpm_compiler.learning.traces import TraceConfig, generate_traces

    cfg = TraceConfig(TOPIARY, str(pipeline / "set"), 2, 4, workers=1, sigma=0.05)
    m = generate_traces(cfg, tmp_path / "soft", False)
    assert m["key"]["sigma"] == 0.05 and m["kept"] == 2
    with pytest.raises(NgpmError, match="differs in sigma") as err:  # resume
        generate_traces(TraceConfig(TOPIARY, cfg.targets, 2, 4, workers=1), tmp_path / "soft")
    assert "\n" not in str(err.value)
    vines = str(REPO / "grammars" / "vines.lsys")
    data = make_dataset(tmp_path / "pics")
    with pytest.raises(NgpmError, match="3D grammar") as err:
        generate_traces(TraceConfig(vines, str(data), 2, 4, workers=1, sigma=0.05), tmp_path / "v")
    assert "\n" not in str(err.value)


def test_new_3d_traces_and_guides_read_frame_windows(pipeline: Path) -> None:
    """Traces recorded now read windows that turn with the turtle: the manifest's key and
    layouts say so, the guide trained on them reads them in SMC; a guide whose layouts
    lack the mark (made before) keeps reading cube windows."""
    from ngpm_runtime.inference.guide import Guide
    from ngpm_runtime.volume.run import canvas_and_features
    from ngpm_runtime.volume.target import VolumeTarget

    program = load_grammar(TOPIARY)
    manifest = json.loads((pipeline / "traces" / "manifest.json").read_text())
    assert manifest["key"]["window"] == "frame"
    assert all("frame" in lay for lay in manifest["layouts"].values())
    guide = Guide.load(pipeline / "g.onnx", program)
    assert guide.feature_window == "frame"
    target = VolumeTarget.from_npz(pipeline / "set" / "blobs3d_0000.npz")
    for window in (guide.feature_window, "cube"):
        _, fm = canvas_and_features(program, None, 2, target, True, None, window)
        assert fm is not None and fm.window == window
