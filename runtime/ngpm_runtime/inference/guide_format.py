"""The names in a guide's ONNX file: what `ngpmc export` (ngpm_compiler/learning/export.py)
writes and `Guide` (guide.py) reads, defined once here (docs/architecture.md section 5).

Per site network `i`: the input `f_<i>` (n, n_f) float32 feature rows, the output `p_<i>`
(n, n_out) proposal parameters, and every parameter and node named `s<i>_<role>`. The numpy
engine (guide.NumpyNet) reads a network that reads features by these parameter names:
`s<i>_cols` (int64 selected feature columns), `s<i>_w1` (hidden, columns), `s<i>_b1`
(hidden), `s<i>_w2` (n_out, hidden), `s<i>_b2` (n_out) and `s<i>_bounds` (n_out) for
`bounds * tanh(tanh(x[:, cols] @ w1' + b1) @ w2' + b2)`, then its kind's head
(sitekinds: log-softmax of the first K columns, sigmoid or softmax).
"""

from __future__ import annotations

ONNX_FORMAT = "ngpm-guide-onnx/1"  # metadata `ngpm_format` of every guide file
NET_PARAMS = ("cols", "w1", "b1", "w2", "b2", "bounds")  # what the numpy engine reads


def input_name(site: int) -> str:
    """The graph input of site network `site`: its raw feature rows."""
    return f"f_{site}"


def output_name(site: int) -> str:
    """The graph output of site network `site`: its proposal parameters."""
    return f"p_{site}"


def param_name(site: int, role: str) -> str:
    """The name of parameter (or node) `role` of site network `site`, e.g. `s3_w1`."""
    return f"s{site}_{role}"
