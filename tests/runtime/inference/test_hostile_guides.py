"""Issue #27, finding 7: hostile guide files. A corpus made here from the bundled guide
(no binary fixtures): each file either loads and proposes exactly as the bundled guide does
(harmless changes) or is refused at load with one GuideError line naming the file and the
cause; never a traceback, a hang or a silently different result."""

from __future__ import annotations

import json
import math
import re
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import onnx
import pytest
from ngpm_runtime import bundled
from ngpm_runtime.errors import GuideError
from ngpm_runtime.inference.guide import Guide, ProposalSettings
from onnx import TensorProto, helper, numpy_helper

Edit = Callable[[onnx.ModelProto], "bytes | None"]
JSON_KEYS = ("sites", "features", "nets", "training", "proposal")
META_KEYS = ("ngpm_format", "grammar", "grammar_hash", "K", *JSON_KEYS)
WRONG_JSON = {
    "list": "[1, 2]",
    "number": "7",
    "null": "null",
    "string": '"x"',
    "nested": '{"a": {"b": {"c": [1, {"d": null}]}}}',
    "invalid": '{"a": ',
    "huge": json.dumps("x" * 3_000_000),
    "deep": "[" * 100_000 + "]" * 100_000,
}


def _bundled() -> onnx.ModelProto:
    return onnx.load(str(bundled.guide_path()))


def _props(model: onnx.ModelProto) -> dict[str, str]:
    return {p.key: p.value for p in model.metadata_props}


def _set_prop(model: onnx.ModelProto, key: str, value: str | None) -> None:
    props = _props(model)
    if value is None:
        props.pop(key, None)
    else:
        props[key] = value
    del model.metadata_props[:]
    helper.set_model_props(model, props)


def meta(key: str, value: str | None) -> Edit:
    return lambda m: _set_prop(m, key, value)


def meta_json(key: str, change: Callable[[object], object]) -> Edit:
    """Edit the JSON in metadata `key`: `change` mutates it in place or returns a new value."""

    def edit(m: onnx.ModelProto) -> None:
        value = json.loads(_props(m)[key])
        new = change(value)
        _set_prop(m, key, json.dumps(value if new is None else new))

    return edit


def net_field(field: str, value: object) -> Edit:
    return meta_json("nets", lambda nets: nets["0"].__setitem__(field, value))


def weight(name: str, change: Callable[[np.ndarray], np.ndarray]) -> Edit:
    """Replace initializer `name` by `change(its array)` (dtype and shape may change)."""

    def edit(m: onnx.ModelProto) -> None:
        t = next(t for t in m.graph.initializer if t.name == name)
        t.CopyFrom(numpy_helper.from_array(change(numpy_helper.to_array(t).copy()), name))

    return edit


def poke(value: float, at: tuple[int, ...] = (0, 0)) -> Callable[[np.ndarray], np.ndarray]:
    def change(a: np.ndarray) -> np.ndarray:
        a[at[: a.ndim]] = value
        return a

    return change


def graph(change: Callable[[onnx.GraphProto], None]) -> Edit:
    return lambda m: change(m.graph)


def _drop_output(g: onnx.GraphProto) -> None:
    keep = [o for o in g.output if o.name != "p_3"]
    del g.output[:]
    g.output.extend(keep)


def _extra_input(g: onnx.GraphProto) -> None:
    g.input.append(helper.make_tensor_value_info("f_99", TensorProto.FLOAT, ["n", 3]))


def _node(g: onnx.GraphProto, name: str) -> onnx.NodeProto:
    return next(n for n in g.node if n.name == name)


def _set_attr(name: str, attr: str, value: int) -> Edit:
    def change(g: onnx.GraphProto) -> None:
        node = _node(g, name)
        kept = [a for a in node.attribute if a.name != attr]
        del node.attribute[:]
        node.attribute.extend([*kept, helper.make_attribute(attr, value)])

    return graph(change)


def _rewire_mul(g: onnx.GraphProto) -> None:
    """Site 0's bounds multiply the raw output, not its tanh (the Tanh node stays)."""
    _node(g, "s0_bounded").input[0] = "s0_raw"


def _rename_weight(g: onnx.GraphProto) -> None:
    """Site 0's first layer weights under another name (onnxruntime still runs the graph)."""
    next(t for t in g.initializer if t.name == "s0_w1").name = "s0_weights"
    _node(g, "s0_h").input[1] = "s0_weights"


def _read_a_copy(g: onnx.GraphProto) -> None:
    """Site 2's second layer reads a changed copy of its weights; s2_w2 stays, unread."""
    w2 = numpy_helper.to_array(next(t for t in g.initializer if t.name == "s2_w2"))
    g.initializer.append(numpy_helper.from_array(w2 * 1.5, "s2_w2_copy"))
    _node(g, "s2_raw").input[1] = "s2_w2_copy"


def _tanh_to_relu(g: onnx.GraphProto) -> None:
    _node(g, "s0_hidden").op_type = "Relu"


def _external_weights(m: onnx.ModelProto) -> None:
    t = next(t for t in m.graph.initializer if t.name == "s0_w1")
    t.ClearField("raw_data")
    t.data_location = TensorProto.EXTERNAL
    for key, value in (("location", "/etc/hostname"), ("offset", "0"), ("length", "40")):
        t.external_data.add(key=key, value=value)


def _other_model(m: onnx.ModelProto) -> bytes:
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])
    g = helper.make_graph([helper.make_node("Neg", ["x"], ["y"])], "other", [x], [y])
    return helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)]).SerializeToString()


def _other_model_labelled(m: onnx.ModelProto) -> bytes:
    other = onnx.load_from_string(_other_model(m))
    helper.set_model_props(other, _props(m))
    return other.SerializeToString()


def _sites(change: Callable[[list], object]) -> Edit:
    return meta_json("sites", change)


def _extra_site(sites: list) -> None:
    sites.append({**sites[-1], "index": len(sites), "id": "X/0/normal0"})


def variants() -> dict[str, tuple[Edit, str]]:
    """name -> (edit of the bundled model, expected outcome): "same" (loads and proposes
    exactly as the bundled guide), "defaults" (the same networks with default settings)
    or a regular expression the GuideError line must match."""
    out: dict[str, tuple[Edit, str]] = {
        "zero bytes": (lambda m: b"", "not a readable ONNX guide"),
        "truncated": (lambda m: m.SerializeToString()[:90_000], "not a readable ONNX guide"),
        "last bytes cut": (lambda m: m.SerializeToString()[:-30], "not a readable ONNX"),
        "not onnx": (
            lambda m: b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 8,
            "not a readable ONNX guide",
        ),
        "another model": (_other_model, "not an ngpm guide"),
        "another model labelled ngpm": (_other_model_labelled, "graph has no input f_0"),
        "format 2": (meta("ngpm_format", "ngpm-guide-onnx/2"), "is newer than"),
        "other grammar": (meta("grammar_hash", "sha256:" + "0" * 64), "trained for grammar"),
        "grammar named huge": (meta("grammar", "v" * 2_000_000), "'grammar' is 2000000 char"),
        "K letters": (meta("K", "four"), "K"),
        "K negative": (meta("K", "-4"), "K"),
        "K float": (meta("K", "4.0"), "K"),
        "K huge": (meta("K", "9" * 5000), "K"),
        "a site missing": (_sites(lambda s: s[:-1]), "site table"),
        "an unknown site": (_sites(_extra_site), "site table does not match"),
        "site row a string": (_sites(lambda s: ["x", *s[1:]]), "sites"),
        "site ids swapped": (_sites(lambda s: [s[1], s[0], *s[2:]]), "site table"),
        "net for an unknown site": (
            meta_json("nets", lambda n: n.__setitem__("8", n["0"])),
            "network for site 8",
        ),
        "net key not a number": (meta_json("nets", lambda n: n.__setitem__("x", n["0"])), "nets"),
        "net row a list": (meta_json("nets", lambda n: n.__setitem__("0", [98, 12])), "nets"),
        "n_f a string": (net_field("n_f", "98"), "n_f"),
        "n_f a float": (net_field("n_f", 98.0), "n_f"),
        "n_f true": (net_field("n_f", True), "n_f"),
        "n_f huge": (net_field("n_f", 10**12), "n_f"),
        "n_out null": (net_field("n_out", None), "n_out"),
        "feature set a number": (
            meta_json("features", lambda f: f.__setitem__("feature_set", 7)),
            "feature_set",
        ),
        "feature set a list": (
            meta_json("features", lambda f: f.__setitem__("feature_set", ["all"])),
            "feature_set",
        ),
        "feature set unknown": (
            meta_json("features", lambda f: f.__setitem__("feature_set", "all+colour")),
            "feature_set",
        ),
        "feature set const": (
            meta_json("features", lambda f: f.__setitem__("feature_set", "const")),
            "feature_set",
        ),
        "feature set without context": (
            meta_json("features", lambda f: f.__setitem__("feature_set", "all")),
            "feature_set",
        ),
        "layouts a list": (
            meta_json("features", lambda f: f.__setitem__("layouts", [])),
            "layouts",
        ),
        "layout group reversed": (
            meta_json("features", lambda f: f["layouts"]["0"].__setitem__("target", [45, 9])),
            "layouts",
        ),
        "layout past n_f": (
            meta_json("features", lambda f: f["layouts"]["0"].__setitem__("context", [81, 99])),
            "reads 98 features, but its layout has 99",
        ),
        "columns strings": (
            meta_json("features", lambda f: f["columns"].__setitem__("0", ["a"])),
            "columns",
        ),
        "columns past n_f": (
            meta_json("features", lambda f: f["columns"]["0"].__setitem__(0, 500)),
            "columns",
        ),
        "training a list": (meta("training", "[1, 2]"), "training"),
        "val_nll a string": (
            meta_json("training", lambda t: t.__setitem__("val_nll", "low")),
            "training",
        ),
        "proposal temperature true": (meta("proposal", '{"temperature": true}'), "proposal"),
        "proposal temperature NaN": (meta("proposal", '{"temperature": NaN}'), "proposal"),
        "proposal unknown key": (meta("proposal", '{"colour": 1}'), "proposal"),
        "NaN weight": (weight("s0_w1", poke(math.nan)), "s0_w1.*not finite"),
        "inf weight": (weight("s1_w2", poke(math.inf)), "s1_w2.*not finite"),
        "-inf bias": (weight("s2_b1", poke(-math.inf, (3,))), "s2_b1.*not finite"),
        "NaN bound": (weight("s4_bounds", poke(math.nan, (1,))), "s4_bounds.*not finite"),
        "huge weight": (weight("s3_w1", poke(1e30)), "s3_w1"),
        "float64 weights": (weight("s0_w1", lambda a: a.astype(np.float64)), "s0_w1|readable ONNX"),
        "int32 columns": (weight("s0_cols", lambda a: a.astype(np.int32)), "s0_cols|readable ONNX"),
        "weights transposed": (weight("s0_w1", lambda a: a.T.copy()), "s0|site 0|readable"),
        "a bias short": (weight("s1_b1", lambda a: a[:-1]), "s1|site 1|readable"),
        "column past the row": (weight("s2_cols", poke(5000, (0,))), "s2_cols|site 2"),
        "huge slice end": (weight("s0_c2", lambda a: a * 10**15), "s0_c2"),
        "weights in another file": (_external_weights, "s0_w1.*external|readable ONNX"),
        "an output missing": (graph(_drop_output), "has no output p_3"),
        "an extra input": (graph(_extra_input), "inputs do not match"),
        "softmax over the batch": (_set_attr("p_2", "axis", 0), "site 2"),
        "log-softmax over the batch": (_set_attr("s0_logw", "axis", 0), "site 0"),
        "concat over the batch": (_set_attr("p_0", "axis", 0), "p_0|fail|readable"),
        "bounds on the raw output": (
            graph(_rewire_mul),
            "site 0 .*does not compute what `ngpmc export` writes .*numpy engine and onnxruntime",
        ),
        "relu for tanh": (graph(_tanh_to_relu), "Relu"),
        "a weight renamed": (
            graph(_rename_weight),
            r"site 0 \(S/0/normal0\) network has no "
            "parameter s0_w1 ",
        ),
        "bounds one number": (
            weight("s1_bounds", lambda a: a[:1] * 0 + 10),
            r"site 1 .*parameter s1_bounds is float32 of shape \[1\]",
        ),
        "the graph reads a copy": (graph(_read_a_copy), "site 2 .*does not compute what"),
        # harmless: the same networks and settings
        "unknown metadata key": (meta("comment", "hello"), "same"),
        "training with extra keys": (
            meta_json("training", lambda t: t.__setitem__("x", [1])),
            "same",
        ),
        "producer renamed": (lambda m: setattr(m, "producer_name", "someone"), "same"),
        "no proposal settings": (meta("proposal", None), "defaults"),
    }
    for key in META_KEYS:
        if key != "proposal":
            out[f"no {key}"] = (
                meta(key, None),
                "not an ngpm guide" if key == "ngpm_format" else f"{key}.*missing",
            )
    for key in JSON_KEYS:
        for kind, text in WRONG_JSON.items():
            out[f"{key} {kind}"] = (meta(key, text), key)
    del out["proposal nested"]  # a settings object with an unknown key: "proposal unknown key"
    out["training nested"] = (out["training nested"][0], "same")  # a summary with other keys
    return out


VARIANTS = variants()


def _write(tmp_path: Path, name: str, edit: Edit) -> Path:
    model = _bundled()
    data = edit(model)
    path = tmp_path / (name.replace(" ", "_") + ".onnx")
    path.write_bytes(model.SerializeToString() if data is None else data)
    return path


def _probe_rows(guide: Guide) -> dict[int, np.ndarray]:
    rng = np.random.default_rng(0)
    return {s: rng.normal(size=(6, n["n_f"])).astype(np.float32) for s, n in guide.nets.items()}


def _same_proposals(guide: Guide, want: Guide) -> None:
    """`guide` proposes as `want` does: the same networks (both engines), settings and
    fallback sites."""
    assert guide.nets == want.nets and guide.fallback_sites == want.fallback_sites
    assert sorted(guide.numpy_nets) == sorted(want.numpy_nets)
    rows = _probe_rows(want)
    for s, x in rows.items():
        np.testing.assert_array_equal(guide.params(s, x), want.params(s, x))
    guide.numpy_nets = {}
    for s, x in rows.items():
        np.testing.assert_allclose(guide.params(s, x), want.params(s, x), rtol=1e-5, atol=1e-5)


def test_the_corpus_is_large() -> None:
    assert len(VARIANTS) >= 40


@pytest.mark.parametrize("name", list(VARIANTS))
def test_hostile_guide(name: str, tmp_path: Path, vines_guide: Guide) -> None:
    edit, expect = VARIANTS[name]
    path = _write(tmp_path, name, edit)
    t0 = time.perf_counter()
    if expect in ("same", "defaults"):
        guide = Guide.load(path, bundled.bundled_program())
        if expect == "defaults":
            assert guide.settings == ProposalSettings()
            guide.settings = vines_guide.settings
        _same_proposals(guide, vines_guide)
    else:
        with pytest.raises(GuideError) as info:
            Guide.load(path, bundled.bundled_program())
        line = str(info.value)
        assert line.startswith(f"{path}: ") and "\n" not in line and len(line) < 400, line
        assert re.search(expect, line), line
    assert time.perf_counter() - t0 < 5


def test_a_numpy_engine_that_disagrees_is_an_error(tmp_path: Path, monkeypatch) -> None:
    """Should the numpy engine of a file that passed the checks give other numbers than
    onnxruntime, the load fails with one line naming the file and the site: no silent
    switch to the other engine."""
    from ngpm_runtime.inference.guide import NumpyNet

    build = NumpyNet.from_params

    def off(where, site, *args):
        net = build(where, site, *args)
        if site == 1:
            net.b1 = net.b1 + 0.5
        return net

    monkeypatch.setattr(NumpyNet, "from_params", off)
    with pytest.raises(GuideError) as info:
        Guide.load(bundled.guide_path(), bundled.bundled_program())
    line = str(info.value)
    assert (
        line.startswith(
            f"{bundled.guide_path()}: site 1 (B/0/normal0) network: its graph does not compute"
        )
        and "\n" not in line
    ), line


def test_a_guide_that_cannot_be_cut_is_an_error(monkeypatch) -> None:
    """Should onnx fail to cut the file into its site networks, the load fails with one line
    naming the file and the cause, not with a guide that quietly runs otherwise."""
    import onnx.utils

    class Broken:
        def __init__(self, model):
            raise RuntimeError("no such node\nsecond line")

    monkeypatch.setattr(onnx.utils, "Extractor", Broken)
    with pytest.raises(GuideError) as info:
        Guide.load(bundled.guide_path(), bundled.bundled_program())
    assert str(info.value) == (
        f"{bundled.guide_path()}: cannot cut the guide into its site networks: no such node"
    )


# --------------------------------------------------------------------------- command line

CLI_VARIANTS = [
    "NaN weight",
    "nets list",
    "features huge",
    "proposal temperature true",
    "truncated",
    "a bias short",
    "other grammar",
    "a weight renamed",
]


@pytest.mark.parametrize("name", CLI_VARIANTS)
def test_grow_with_a_hostile_guide(name: str, tmp_path: Path, capsys) -> None:
    """`ngpmc grow pic.png --guide bad.onnx -o out.png`: exit code != 0, one line on stderr,
    no traceback, no output file."""
    from ngpm_compiler.cli import main

    bad = _write(tmp_path, name, VARIANTS[name][0])
    src = bundled.demo_target_path("horse")
    pic = tmp_path / "pic.png"
    pic.write_bytes(src.read_bytes())
    (tmp_path / "pic.txt").write_bytes(src.with_suffix(".txt").read_bytes())
    out = tmp_path / "out.png"
    code = main(["grow", str(pic), "--guide", str(bad), "-N", "2", "-o", str(out)])
    err = capsys.readouterr().err
    assert code != 0 and err.count("\n") == 1 and "Traceback" not in err, err
    assert err.startswith(f"ngpmc: error: {bad}: ") and not out.exists()


def test_grow_with_a_hostile_guide_in_a_process(tmp_path: Path) -> None:
    """The same through the installed command's code path, in its own process (onnxruntime
    logs nothing more to stderr)."""
    import subprocess
    import sys

    bad = _write(tmp_path, "a bias short", VARIANTS["a bias short"][0])
    out = tmp_path / "out.png"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "ngpm_compiler.cli",
            "grow",
            str(bundled.demo_target_path("horse")),
            "--guide",
            str(bad),
            "-o",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode != 0 and proc.stderr.count("\n") == 1, proc.stderr
    assert proc.stderr.startswith(f"ngpmc: error: {bad}: the guide's networks fail")
    assert not out.exists()


def test_without_the_onnx_package_the_probe_run_refuses(tmp_path: Path) -> None:
    """The runtime installed alone has no `onnx` package, so no parameter checks: the bundled
    guide still loads (onnxruntime only), and the probe run refuses NaN weights and a graph
    that cannot run."""
    import textwrap

    from blocked_imports import run_blocked

    bad = [
        str(_write(tmp_path, name, VARIANTS[name][0]))
        for name in ("NaN weight", "a bias short", "softmax over the batch")
    ]
    body = textwrap.dedent("""
        from ngpm_runtime import bundled
        from ngpm_runtime.errors import GuideError
        from ngpm_runtime.inference.guide import Guide

        g = Guide.load(bundled.guide_path(), bundled.bundled_program())
        assert g.numpy_nets == {} and g.site_sessions == {} and len(g.nets) == 8
        for path in sys.argv[1:]:
            try:
                Guide.load(path, bundled.bundled_program())
            except GuideError as err:
                print(err)
            else:
                raise AssertionError(path + " loaded")
        """)
    proc = run_blocked(
        body, tmp_path, *bad, blocked=("onnx", "torch", "ngpm_compiler"), timeout=120
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.splitlines()
    assert lines[-1] == "ok" and len(lines) == 4, proc.stdout
    assert (
        "s0_w1" not in lines[0]
        and "site 0 (S/0/normal0) network gives values that are not finite" in lines[0]
    )
    assert "networks fail on test rows" in lines[1] and "do not sum to 1" in lines[2]
