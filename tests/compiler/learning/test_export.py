"""Export: torch and onnxruntime agree; the ONNX file checks; Guide.load rejects bad files."""

from __future__ import annotations

import json

import numpy as np
import onnx
import pytest
import torch
from fixtures.guides import N_F, SITES, fake_program, random_model
from ngpm_runtime.errors import GuideError
from ngpm_runtime.inference.guide import Guide
from ngpm_runtime.program import Site

from ngpm_compiler.learning.export import build_onnx, write_onnx


@pytest.mark.parametrize("K", [1, 4])
@pytest.mark.parametrize("feature_set", ["const", "local", "all"])
def test_torch_and_onnxruntime_agree(tmp_path, K, feature_set):
    model = random_model(K, feature_set, seed=K)
    path = write_onnx(model, tmp_path / "g.onnx")
    onnx.checker.check_model(onnx.load(str(path)), full_check=True)
    guide = Guide.load(path, fake_program())
    rng = np.random.default_rng(1)
    for site in SITES:
        for n in (1, 7, 300):
            x = (rng.normal(size=(n, N_F)) * 3).astype(np.float32)
            with torch.no_grad():
                ref = model.nets[site.index](torch.from_numpy(x)).numpy()
            got = guide.params(site.index, x)
            assert got.shape == ref.shape == (n, model.nets[site.index].spec.n_out)
            np.testing.assert_allclose(got, ref, atol=1e-5, rtol=0)
            if site.kind in ("normal", "uniform"):  # log weights normalized
                np.testing.assert_allclose(np.exp(got[:, :K]).sum(1), 1, atol=1e-5)
            elif site.kind == "categorical":
                np.testing.assert_allclose(got.sum(1), 1, atol=1e-5)
                assert got.min() > 0


def test_metadata(tmp_path):
    model = random_model(4, "local+target")
    proto = build_onnx(model)
    props = {p.key: p.value for p in proto.metadata_props}
    assert props["grammar_hash"] == "sha256:abc" and props["K"] == "4"
    assert [s["id"] for s in json.loads(props["sites"])] == [s.id for s in SITES]
    features = json.loads(props["features"])
    assert features["feature_set"] == "local+target"
    assert features["columns"]["0"] == list(range(9))
    assert json.loads(props["training"]) == {"epochs": 0}
    assert [i.name for i in proto.graph.input] == ["f_0", "f_1", "f_2", "f_3"]
    assert [o.name for o in proto.graph.output] == ["p_0", "p_1", "p_2", "p_3"]


def test_fallback_sites(tmp_path):
    path = write_onnx(random_model(4, "all", skip=(1, 3)), tmp_path / "g.onnx")
    guide = Guide.load(path, fake_program())
    assert guide.fallback_sites == [1, 3]
    assert guide.uses_features


def test_rejects_other_grammar_and_bad_files(tmp_path):
    path = write_onnx(random_model(4, "all"), tmp_path / "g.onnx")
    with pytest.raises(GuideError, match="trained for grammar"):
        Guide.load(path, fake_program(grammar_hash="sha256:other"))
    other_sites = [*SITES[:3], Site(index=3, id="B/choice", kind="categorical", k=3)]
    with pytest.raises(GuideError, match="site table"):
        Guide.load(path, fake_program(sites=other_sites))
    data = path.read_bytes()
    bad = tmp_path / "truncated.onnx"
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(GuideError, match="corrupt or truncated"):
        Guide.load(bad, fake_program())
    bad.write_bytes(b"not an onnx file at all")
    with pytest.raises(GuideError):
        Guide.load(bad, fake_program())
    with pytest.raises(GuideError, match="no such"):
        Guide.load(tmp_path / "missing.onnx", fake_program())
    guide = Guide.load(path, fake_program())
    with pytest.raises(GuideError, match="expects 12 features"):
        guide.params(0, np.zeros((3, 5), np.float32))


def test_written_files_follow_the_umask(tmp_path):
    import os

    umask = os.umask(0o022)
    try:
        path = write_onnx(random_model(1, "local"), tmp_path / "g.onnx")
    finally:
        os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o644
    assert [p.name for p in tmp_path.iterdir()] == ["g.onnx"]  # no temp file left
