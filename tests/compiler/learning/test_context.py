"""The context and far feature groups end to end: traces record them, `all+context` and
`all+context+far` guides read them, `all` guides trained on the same traces read rows
without them."""

from __future__ import annotations

import numpy as np
import pytest
from fixtures.datasets import CHAIN, make_dataset
from ngpm_runtime.grow import grow
from ngpm_runtime.image.features import N_CONTEXT, N_FAR
from ngpm_runtime.image.targets import load_target
from ngpm_runtime.inference.guide import Guide
from ngpm_runtime.inference.smc import TraceRecording

from ngpm_compiler.language.compile import load_grammar
from ngpm_compiler.learning.export import write_onnx
from ngpm_compiler.learning.trace_data import load_traces
from ngpm_compiler.learning.traces import TraceConfig, generate_traces
from ngpm_compiler.learning.train import TrainConfig, train_guide


@pytest.fixture(scope="module")
def traces(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("context")
    data = make_dataset(tmp / "data")
    generate_traces(
        TraceConfig(grammar=CHAIN, targets=str(data), n=6, particles=8, seed=1, workers=1),
        tmp / "traces",
        progress=False,
    )
    return tmp, data, load_traces(tmp / "traces")


def test_traces_record_the_context_group(traces) -> None:
    _, _, ts = traces
    lay = ts.layouts[0]
    assert lay["context"] == slice(lay["partial"].stop, lay["partial"].stop + N_CONTEXT)
    assert lay["far"] == slice(lay["context"].stop, lay["context"].stop + N_FAR)
    f = ts.data[0].features
    assert f.shape[1] == lay["far"].stop
    ctx = f[:, lay["context"]]
    assert ((ctx[:, :2] >= 0) & (ctx[:, :2] <= 1.5)).all()  # fractions of the target
    assert ((ctx[:, 2:] >= -1) & (ctx[:, 2:] <= 1)).all()  # look-ahead samples
    assert (ctx[:, 2:] > 0).any() and (ctx[:, 0] < 1).any()  # the chain fills its bar
    far = f[:, lay["far"]]
    assert ((far >= -1) & (far <= 1)).all() and (far == -1).any()  # some points leave the image


@pytest.mark.parametrize("feature_set", ["all", "all+context", "all+context+far"])
def test_guides_with_and_without_context(traces, feature_set) -> None:
    tmp, data, ts = traces
    program = load_grammar(CHAIN)
    model = train_guide(
        ts.sites,
        ts.layouts,
        ts.data,
        TrainConfig(feature_set=feature_set, epochs=2, val_fraction=0.0),
        grammar=program.name,
        grammar_hash=program.grammar_hash,
    )
    path = write_onnx(model, tmp / f"{feature_set}.onnx")
    guide = Guide.load(path, program)
    lay = ts.layouts[0]
    wants_context = "context" in feature_set
    assert guide.feature_context is wants_context
    assert guide.feature_far is feature_set.endswith("far")
    last = "far" if guide.feature_far else "context" if wants_context else "partial"
    assert guide.nets[0]["n_f"] == lay[last].stop
    target = load_target(data / "bar0.png")
    res = grow(program, target, guide, 6, seed=2, trace=TraceRecording.FULL)
    assert np.isfinite(res.smc.log_evidence)
    # every recorded row (context and far included) is scored by the guide as SMC proposed
    # with it
    for s, row, _ in res.smc.best.trace:
        assert row.shape == (lay["far"].stop,)
        assert guide.params(s, row[None, :]).shape[0] == 1
    # seeded runs repeat
    again = grow(program, target, guide, 6, seed=2)
    assert again.similarity == res.similarity
