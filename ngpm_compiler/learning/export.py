"""Export a trained guide (model.pt) to ONE .onnx file that ngpm_runtime.inference.guide loads.

The graph holds every site network side by side: per site an input `f_<index>` (raw feature
rows, float32, batch dimension `n_<index>`), an output `p_<index>` (section-5 proposal
parameters) and parameters and nodes named `s<index>_<role>`: the names the runtime reads
(ngpm_runtime.inference.guide_format), in the same order in every export. The graph
computes `SiteNet.forward` with few nodes (folded affine ops); torch and onnxruntime agree to
float rounding (tests/compiler/learning/test_export.py). onnxruntime needs every graph input
fed, so the runtime feeds empty batches for the other sites and fetches only `p_<index>`.

metadata_props: ngpm_format, grammar, grammar_hash, sites (site table JSON), features (feature
set, per-site layout, widths and selected columns), nets (per-site kind / sizes), K, training.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import torch
from ngpm_runtime.files import atomic_write
from ngpm_runtime.inference.guide_format import (
    ONNX_FORMAT,
    input_name,
    output_name,
    param_name,
)
from ngpm_runtime.inference.sitekinds import MIXTURE, SIGMOID
from onnx import TensorProto, helper, numpy_helper

from ngpm_compiler.learning.nets import GuideModel, SiteNet, output_bounds

OPSET = 17
IR_VERSION = 8  # onnxruntime >= 1.16 reads it


class _Graph:
    """Collects nodes and constants for one ONNX graph."""

    def __init__(self) -> None:
        self.nodes: list[onnx.NodeProto] = []
        self.inits: list[onnx.TensorProto] = []

    def const(self, name: str, value: np.ndarray) -> str:
        self.inits.append(numpy_helper.from_array(np.asarray(value), name))
        return name

    def op(self, op_type: str, inputs: list[str], output: str, **attrs: Any) -> str:
        self.nodes.append(helper.make_node(op_type, inputs, [output], name=output, **attrs))
        return output


def _f32(t: torch.Tensor) -> np.ndarray:
    return np.asarray(t.detach().cpu().numpy(), dtype=np.float32)


def _f64(t: torch.Tensor) -> np.ndarray:
    return np.asarray(t.detach().double().numpy())


def _site_graph(g: _Graph, index: int, net: SiteNet) -> str:
    """Add one site's network; returns the name of its output.

    Lean form of SiteNet.forward (few nodes: onnxruntime's cost is per node): the input
    standardization is folded into the first Gemm, the 1/b of the bounding transforms into
    the second; a feature-free net's output is a constant row expanded to the batch."""
    s, p = net.spec, param_name(index, "")
    x, out = input_name(index), output_name(index)
    if net.l1 is None or net.l2 is None:
        with torch.no_grad():
            row = _f32(net(torch.zeros(1, s.n_f)))
        shape = g.op("Shape", [x], p + "shape")
        n = g.op(
            "Slice",
            [shape, g.const(p + "s0", np.array([0])), g.const(p + "s1", np.array([1]))],
            p + "n",
        )
        target = g.op("Concat", [n, g.const(p + "nout", np.array([s.n_out]))], p + "target", axis=0)
        return g.op("Expand", [g.const(p + "row", row), target], out)
    w1 = _f64(net.l1.weight) * _f64(net.scale)[None, :]
    b1 = _f64(net.l1.bias) - w1 @ _f64(net.shift)
    bounds = output_bounds(s)
    inv_b = 1.0 / bounds
    w2 = _f64(net.l2.weight) * inv_b[:, None]
    b2 = _f64(net.l2.bias) * inv_b
    sel = g.op(
        "Gather", [x, g.const(p + "cols", np.array(s.cols, dtype=np.int64))], p + "sel", axis=1
    )
    h = g.op(
        "Gemm",
        [sel, g.const(p + "w1", w1.astype(np.float32)), g.const(p + "b1", b1.astype(np.float32))],
        p + "h",
        transB=1,
    )
    h = g.op("Tanh", [h], p + "hidden")
    raw = g.op(
        "Gemm",
        [h, g.const(p + "w2", w2.astype(np.float32)), g.const(p + "b2", b2.astype(np.float32))],
        p + "raw",
        transB=1,
    )
    bounded = g.op(
        "Mul",
        [g.op("Tanh", [raw], p + "tanh"), g.const(p + "bounds", bounds.astype(np.float32))],
        p + "bounded",
    )
    head = s.site_kind.head
    if head == MIXTURE:
        K = s.K
        axes = g.const(p + "axes", np.array([1]))
        cut = [g.const(p + f"c{i}", np.array([v])) for i, v in enumerate((0, K, 3 * K))]
        logits = g.op("Slice", [bounded, cut[0], cut[1], axes], p + "logits")
        rest = g.op("Slice", [bounded, cut[1], cut[2], axes], p + "rest")
        logw = g.op("LogSoftmax", [logits], p + "logw", axis=1)
        return g.op("Concat", [logw, rest], out, axis=1)
    if head == SIGMOID:
        return g.op("Sigmoid", [bounded], out)
    return g.op("Softmax", [bounded], out, axis=1)


def build_onnx(model: GuideModel) -> onnx.ModelProto:
    """One ONNX model holding every site network of `model`, with metadata."""
    g = _Graph()
    inputs, outputs = [], []
    for index in sorted(model.nets):
        net = model.nets[index]
        inputs.append(
            helper.make_tensor_value_info(
                input_name(index), TensorProto.FLOAT, [f"n_{index}", net.spec.n_f]
            )
        )
        _site_graph(g, index, net)
        outputs.append(
            helper.make_tensor_value_info(
                output_name(index), TensorProto.FLOAT, [f"n_{index}", net.spec.n_out]
            )
        )
    graph = helper.make_graph(g.nodes, f"ngpm_guide_{model.grammar}", inputs, outputs, g.inits)
    proto = helper.make_model(
        graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="ngpmc export"
    )
    proto.ir_version = IR_VERSION
    nets = {
        str(i): {
            "kind": n.spec.kind,
            "n_f": n.spec.n_f,
            "n_out": n.spec.n_out,
            "K": n.spec.K,
            "k": n.spec.k,
            "hidden": n.spec.hidden,
        }
        for i, n in sorted(model.nets.items())
    }
    features = {
        "feature_set": model.feature_set,
        "layouts": {str(i): v for i, v in sorted(model.layouts.items())},
        "columns": {str(i): n.spec.cols for i, n in sorted(model.nets.items())},
    }
    meta = {
        "ngpm_format": ONNX_FORMAT,
        "grammar": model.grammar,
        "grammar_hash": model.grammar_hash,
        "sites": json.dumps(model.sites),
        "features": json.dumps(features),
        "nets": json.dumps(nets),
        "K": str(model.K),
        "training": json.dumps(model.summary),
    }
    helper.set_model_props(proto, meta)
    onnx.checker.check_model(proto, full_check=True)
    return proto


def write_onnx(model: GuideModel, path: str | Path) -> Path:
    """Build, check and atomically write the guide's ONNX file."""
    return atomic_write(path, build_onnx(model).SerializeToString())
