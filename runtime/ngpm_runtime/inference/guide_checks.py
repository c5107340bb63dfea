"""What `Guide.load` (guide.py) checks in a guide file besides its format and grammar, so
that a damaged or hostile file is refused at load, never run: its size (`read_guide`); the
metadata's schema, types, lengths and ranges (`read_meta`); with the `onnx` package, the
graph's operators and every network parameter: float32 or int64, finite, in range, stored
in the file (`check_model`); and one probe run of every site network, whose outputs must be
valid proposal parameters (`check_outputs`, docs/architecture.md section 5). Each failure is
one GuideError line naming the file and the field.

Without the `onnx` package the probe run is the only check of the networks: NaN weights
fail it, but an inf or huge weight whose outputs stay finite is not seen.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ngpm_runtime.errors import GuideError
from ngpm_runtime.image.features import FEATURE_GROUPS, last_group
from ngpm_runtime.inference.distributions import kind_of
from ngpm_runtime.inference.guide_format import input_name
from ngpm_runtime.program import Program, Site

MAX_GUIDE_BYTES = 256 * 2**20  # the bundled guide is 0.2 MB
MAX_META_CHARS = 2**20  # per metadata value
MAX_NAME = 200  # characters of the grammar's name and hash
MAX_WIDTH = 100_000  # features, outputs, hidden units or sites
MAX_K = 1000  # mixture components
MAX_WEIGHT = 1e12  # |float parameter|; export's are far smaller (inputs scale by <= 1e6)
MAX_INT = 1_000_000  # |integer constant|: column indices and widths
JSON_KEYS = ("sites", "features", "nets", "training")
# "frame": an empty group, the mark of 3D windows that turn with the turtle (volume/features)
GROUPS = ("local", "target", "partial", "frame", "context", "far")
# the operators `ngpmc export` writes; all cost linear time
GUIDE_OPS = frozenset(
    {
        "Gather",
        "Gemm",
        "Tanh",
        "Mul",
        "Slice",
        "LogSoftmax",
        "Softmax",
        "Sigmoid",
        "Concat",
        "Shape",
        "Expand",
    }
)
PROBE_ROWS = 5
TOL = 1e-3  # on the sums of probabilities and of mixture weights


def show(value: Any) -> str:
    """`repr(value)`, cut to 40 characters."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _bad(path: str, field: str, want: str, got: Any) -> GuideError:
    return GuideError(f"{path}: guide metadata {field} must be {want}, got {show(got)}")


def read_guide(path: str) -> bytes:
    """The file's bytes (GuideError if missing, unreadable or too large)."""
    p = Path(path)
    if not p.is_file():
        raise GuideError(f"{path}: no such guide file")
    try:
        size = p.stat().st_size
        if size > MAX_GUIDE_BYTES:
            raise GuideError(
                f"{path}: guide file is {size / 2**20:.0f} MB; ngpm reads guides "
                f"of up to {MAX_GUIDE_BYTES // 2**20} MB"
            )
        return p.read_bytes()
    except OSError as err:
        raise GuideError(f"{path}: cannot read the guide ({err.strerror or err})") from None


def parse_json(path: str, key: str, text: str) -> Any:
    """Metadata value `key` as JSON (GuideError if too long or not JSON)."""
    if len(text) > MAX_META_CHARS:
        raise GuideError(
            f"{path}: guide metadata {key!r} is {len(text) / 2**20:.1f} MB; "
            f"at most {MAX_META_CHARS // 2**20} MB"
        )
    try:
        return json.loads(text)
    except (ValueError, RecursionError):
        raise GuideError(
            f"{path}: guide metadata {key!r} is not valid JSON (corrupt file?)"
        ) from None


def read_meta(path: str, props: dict[str, str]) -> dict[str, Any]:
    """The guide metadata `Guide` reads, parsed and checked (GuideError naming the field)."""
    meta: dict[str, Any] = {}
    for key in ("grammar", "grammar_hash", "K", *JSON_KEYS):
        if key not in props:
            raise GuideError(f"{path}: guide metadata {key!r} is missing (corrupt file?)")
        meta[key] = parse_json(path, key, props[key]) if key in JSON_KEYS else props[key]
    for key in ("grammar", "grammar_hash"):
        if len(meta[key]) > MAX_NAME:
            raise GuideError(
                f"{path}: guide metadata {key!r} is {len(meta[key])} characters "
                f"long; at most {MAX_NAME}"
            )
    k = meta["K"]
    if not (k.isascii() and k.isdigit() and len(k) < 6 and 1 <= int(k) <= MAX_K):
        raise _bad(path, "'K'", f"a whole number from 1 to {MAX_K}", k)
    _check_sites(path, meta["sites"])
    _check_nets(path, meta["nets"], len(meta["sites"]))
    _check_features(path, meta["features"], meta["nets"])
    _check_training(path, meta["training"])
    return meta


def _is_int(v: Any, lo: int = 0, hi: int = MAX_WIDTH) -> bool:
    return type(v) is int and lo <= v <= hi


def _check_sites(path: str, sites: Any) -> None:
    if not isinstance(sites, list) or len(sites) > MAX_WIDTH:
        raise _bad(path, "'sites'", "a list of sites", sites)
    for j, s in enumerate(sites):
        if not (
            isinstance(s, dict)
            and isinstance(s.get("id"), str)
            and isinstance(s.get("kind"), str)
            and (s.get("k") is None or _is_int(s.get("k")))
        ):
            raise _bad(path, f"'sites'[{j}]", "a site (id, kind, k)", s)


def _check_nets(path: str, nets: Any, n_sites: int) -> None:
    if not isinstance(nets, dict):
        raise _bad(path, "'nets'", "an object of site networks", nets)
    for key, net in nets.items():
        where = f"'nets'[{key!r}]"
        if not (key.isascii() and key.isdigit() and len(key) <= 6):
            raise _bad(path, "'nets' keys", "site indices", key)
        if int(key) >= n_sites:
            raise GuideError(
                f"{path}: guide has a network for site {key}, but its site table "
                f"has {n_sites} sites"
            )
        if not isinstance(net, dict):
            raise _bad(path, where, "a network's sizes", net)
        for field in ("n_f", "n_out", "K", "hidden"):
            if not _is_int(net.get(field), 1 if field in ("n_f", "n_out") else 0):
                raise _bad(
                    path, f"{where}[{field!r}]", f"a whole number up to {MAX_WIDTH}", net.get(field)
                )
        if not isinstance(net.get("kind"), str):
            raise _bad(path, f"{where}['kind']", "a site kind", net.get("kind"))
        if net.get("k") is not None and not _is_int(net.get("k")):
            raise _bad(path, f"{where}['k']", "a number of categories", net.get("k"))


def _check_features(path: str, features: Any, nets: dict[str, Any]) -> None:
    """The feature set, and per site network its layout and selected columns: what the
    runtime's rows hold (image/features.py) and what the network reads of them."""
    if not isinstance(features, dict):
        raise _bad(path, "'features'", "an object", features)
    fs = features.get("feature_set")
    if not isinstance(fs, str) or fs not in FEATURE_GROUPS:
        raise _bad(path, "'features'['feature_set']", f"one of {', '.join(FEATURE_GROUPS)}", fs)
    layouts = _site_table(path, features, "layouts")
    columns = _site_table(path, features, "columns")
    for key, net in nets.items():
        layout = _check_layout(path, key, layouts.get(key))
        # rows end at the last group the network reads (features.last_group)
        last = last_group(fs)
        missing = [g for g in (*FEATURE_GROUPS[fs], last) if g not in layout]
        if missing:
            raise _bad(
                path,
                f"'features'['layouts'][{key!r}]",
                f"a layout with the {missing[0]!r} columns of feature set {fs!r}",
                layout,
            )
        if layout[last][1] != net["n_f"]:
            raise GuideError(
                f"{path}: site {key} network reads {net['n_f']} features, but its "
                f"layout has {layout[last][1]} up to the {last!r} group"
            )
        want = [c for g in FEATURE_GROUPS[fs] for c in range(*layout[g])]
        if columns.get(key) != want:
            raise _bad(
                path,
                f"'features'['columns'][{key!r}]",
                f"the columns of feature set {fs!r} in its layout",
                columns.get(key),
            )


def _site_table(path: str, features: dict[str, Any], name: str) -> dict[str, Any]:
    """`features[name]`, which must be an object (one entry per site)."""
    value = features.get(name)
    if not isinstance(value, dict):
        raise _bad(path, f"'features'[{name!r}]", "an object per site", value)
    return value


def _check_layout(path: str, key: str, layout: Any) -> dict[str, list[int]]:
    """Site `key`'s layout: groups of [start, stop) columns, one after the other from 0."""
    where = f"'features'['layouts'][{key!r}]"
    if not isinstance(layout, dict) or set(layout) - set(GROUPS):
        raise _bad(path, where, f"column ranges of groups {', '.join(GROUPS)}", layout)
    stop = 0
    for group, span in layout.items():
        if not (
            isinstance(span, list)
            and len(span) == 2
            and _is_int(span[0], stop, stop)
            and _is_int(span[1], stop)
        ):
            raise _bad(path, f"{where}[{group!r}]", f"[{stop}, stop] with stop >= {stop}", span)
        stop = span[1]
    return layout


def _check_training(path: str, training: Any) -> None:
    """The training summary: free-form, but what `bundled.guide_summary` prints is typed."""
    if not isinstance(training, dict):
        raise _bad(path, "'training'", "an object (the training summary)", training)
    for key in ("traces", "val_traces", "best_epoch", "epochs_run", "val_nll"):
        v = training.get(key)
        number = type(v) in (int, float) if key == "val_nll" else _is_int(v, 0, 2**62)
        if v is not None and not number:
            raise _bad(path, f"'training'[{key!r}]", "a number", v)


def check_model(path: str, model: Any, meta: dict[str, Any]) -> dict[str, np.ndarray]:
    """GuideError unless the ONNX graph uses only the operators export writes and every
    parameter is a float32 or int64 tensor stored in the file, finite and in range, and each
    network reads the feature columns its metadata lists. Returns the parameters by name."""
    from onnx import numpy_helper

    graph = model.graph
    for node in graph.node:
        if node.op_type not in GUIDE_OPS or node.domain not in ("", "ai.onnx"):
            raise GuideError(
                f"{path}: the guide's graph uses operator {node.op_type!r} "
                f"({node.name}), which ngpm guides do not use"
            )
    if len(graph.sparse_initializer) or len(model.functions):
        raise GuideError(
            f"{path}: the guide's graph holds sparse tensors or functions, "
            "which ngpm guides do not use"
        )
    consts = {}
    for t in graph.initializer:
        if t.data_location == t.EXTERNAL:
            raise GuideError(
                f"{path}: parameter {t.name} keeps its data in another file; "
                "ngpm guides hold all of theirs"
            )
        a = consts[t.name] = numpy_helper.to_array(t)
        _check_values(path, t.name, a)
    _check_columns(path, graph, consts, meta)
    return consts


def _check_values(path: str, name: str, a: np.ndarray) -> None:
    if a.dtype == np.float32:
        if not np.isfinite(a).all():
            raise GuideError(
                f"{path}: parameter {name} is not finite (NaN or inf): damaged weights"
            )
        if a.size and np.abs(a).max() > MAX_WEIGHT:
            raise GuideError(
                f"{path}: parameter {name} holds {np.abs(a).max():.3g}; "
                f"guide weights are at most {MAX_WEIGHT:g} in size"
            )
    elif a.dtype == np.int64:
        if a.size and np.abs(a).max() > MAX_INT:
            raise GuideError(
                f"{path}: parameter {name} holds {np.abs(a).max()}; the guide's "
                f"integer constants are at most {MAX_INT}"
            )
    else:
        raise GuideError(
            f"{path}: parameter {name} is {a.dtype}; ngpm guides hold float32 and int64 tensors"
        )


def _check_columns(
    path: str, graph: Any, consts: dict[str, np.ndarray], meta: dict[str, Any]
) -> None:
    """Each site network reads its input through one Gather of the metadata's columns (a
    const network only through Shape)."""
    columns = meta["features"]["columns"]
    for key in meta["nets"]:
        name = input_name(int(key))
        readers = [n for n in graph.node if name in n.input]
        cols = columns[key]
        ok = (
            all(n.op_type == "Shape" for n in readers)
            if not cols
            else len(readers) == 1
            and readers[0].op_type == "Gather"
            and readers[0].input[0] == name
            and consts.get(readers[0].input[1], np.empty(0)).tolist() == cols
        )
        if not ok:
            raise GuideError(
                f"{path}: site {key} network does not read the feature columns "
                "its metadata lists (damaged file?)"
            )


def probe_rows(nets: dict[int, dict[str, Any]]) -> dict[int, np.ndarray]:
    """Fixed float32 feature rows (PROBE_ROWS per site network) to try the networks on."""
    rows = {}
    for i, net in nets.items():
        n_f = net["n_f"]
        ramp = np.linspace(-1.0, 1.0, n_f)
        rows[i] = np.stack(
            [np.zeros(n_f), ramp, -2 * ramp, np.cos(np.arange(n_f)), 3 * np.sin(np.arange(n_f))]
        ).astype(np.float32)
    return rows


def expected_outputs(site: Site, K: int) -> int:
    """Columns of a site network's output (docs/architecture.md section 5)."""
    return kind_of(site).n_out(K, int(site.k or 0))


def check_outputs(path: str, outputs: dict[int, np.ndarray], program: Program, K: int) -> None:
    """GuideError unless every site network's outputs on `probe_rows` are valid proposal
    parameters of its site's kind (finite; probabilities and mixture weights sum to 1)."""
    for i, out in outputs.items():
        site = program.sites[i]
        why = _invalid(site, np.asarray(out, dtype=np.float64), K)
        if why:
            raise GuideError(
                f"{path}: site {i} ({site.id}) network gives {why} on test "
                "rows (damaged weights or graph?)"
            )


def _invalid(site: Site, out: np.ndarray, K: int) -> str:
    """Why `out` (PROBE_ROWS rows) are not proposal parameters of `site`; '' if they are."""
    if out.shape != (PROBE_ROWS, expected_outputs(site, K)):
        return f"outputs of shape {list(out.shape)}"
    if not np.isfinite(out).all():
        return "values that are not finite"
    return kind_of(site).output_problem(out, K, TOL)
