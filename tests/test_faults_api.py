"""Issue #12, Python API: bad input raises one clear error that names the cause."""

from __future__ import annotations

from pathlib import Path

import onnx
import pytest
from ngpm_runtime import bundled
from ngpm_runtime.errors import GuideError
from ngpm_runtime.guide import Guide


def _edited_guide(tmp_path: Path, edit) -> Path:
    model = onnx.load(str(bundled.guide_path()))
    edit(model)
    path = tmp_path / "edited.onnx"
    onnx.save(model, str(path))
    return path


def test_guide_without_a_site_output_fails_at_load(tmp_path: Path) -> None:
    """The graph lacks p_3 though the metadata (intact) lists a network for site 3."""
    def drop_output(model):
        keep = [o for o in model.graph.output if o.name != "p_3"]
        del model.graph.output[:]
        model.graph.output.extend(keep)

    path = _edited_guide(tmp_path, drop_output)
    with pytest.raises(GuideError, match=r"has no output p_3 for site 3 .*metadata lists"):
        Guide.load(path, bundled.bundled_program())


def test_guide_with_a_wrong_input_shape_fails_at_load(tmp_path: Path) -> None:
    def narrow(model):
        inp = next(i for i in model.graph.input if i.name == "f_0")
        inp.type.tensor_type.shape.dim[1].dim_value -= 1

    path = _edited_guide(tmp_path, narrow)
    with pytest.raises(GuideError, match=r"input f_0 has shape .* the metadata says"):
        Guide.load(path, bundled.bundled_program())


def test_guide_of_a_future_format_names_the_version(tmp_path: Path) -> None:
    def future(model):
        for prop in model.metadata_props:
            if prop.key == "ngpm_format":
                prop.value = "ngpm-guide-onnx/2"

    path = _edited_guide(tmp_path, future)
    with pytest.raises(GuideError, match=r"guide format ngpm-guide-onnx/2 is newer than the "
                                         r"ngpm-guide-onnx/1 this ngpm reads"):
        Guide.load(path, bundled.bundled_program())


def test_intact_guide_still_loads() -> None:
    g = Guide.load(bundled.guide_path(), bundled.bundled_program())
    assert g.nets
