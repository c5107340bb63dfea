"""The numpy site network the compiled kernel replaced (ngpm_runtime/kernels.py
guide_round), kept as the tests' reference: `numpy_forward` is guide.NumpyNet.__call__
before the kernel (git history: runtime/ngpm_runtime/inference/guide.py)."""

from __future__ import annotations

import numpy as np
from ngpm_runtime.inference.guide import NumpyNet
from ngpm_runtime.inference.sitekinds import MIXTURE, SIGMOID


def numpy_forward(net: NumpyNet, x: np.ndarray) -> np.ndarray:
    """(n, n_out) float64 proposal parameters for float32 feature rows (n, n_f)."""
    h = (x if net.cols is None else x[:, net.cols]) @ net.w1t
    h += net.b1
    np.tanh(h, out=h)
    o = h @ net.w2t
    o += net.b2
    np.tanh(o, out=o)
    o *= net.bounds
    if net.head == MIXTURE:
        lw = o[:, : net.k]
        d = lw - lw.max(axis=1, keepdims=True)
        lw[:] = d - np.log(np.exp(d).sum(axis=1, keepdims=True))
    elif net.head == SIGMOID:
        o = 1 / (1 + np.exp(-o))
    else:
        o = np.exp(o - o.max(axis=1, keepdims=True))
        o /= o.sum(axis=1, keepdims=True)
    return o.astype(np.float64)
