"""Guide networks (torch): one small MLP per site, as in the NGPM paper.

A network takes the site's full raw feature row `(n, n_f)`, selects its columns, standardizes
them with the training set's mean/std (a first affine op, so the runtime feeds raw features),
applies one tanh hidden layer and maps the outputs through bounding transforms into the
proposal parameters of docs/architecture.md section 5. What they are for each site kind
comes from the runtime's table (ngpm_runtime.inference.sitekinds): the output columns and
the head, a mixture (log weights, means, log sds: normal and uniform sites), a sigmoid
(bernoulli: the probability of 1) or a softmax (categorical: k probabilities).

`SiteNet.log_prob` scores training targets (continuous values already mapped to z, see
`continuous_z`); export.py rebuilds `SiteNet.forward` op by op in ONNX.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch
from ngpm_runtime.errors import NgpmError
from ngpm_runtime.image.features import FEATURE_GROUPS, FEATURE_SETS
from ngpm_runtime.inference.sitekinds import KINDS, MIXTURE, SIGMOID, SiteKind
from torch import nn

MIN_HIDDEN = 8
MEAN_BOUND = 10.0  # |mixture mean| in prior units (normal) or in logit space (uniform)
LOGSD_BOUND = 5.0  # |log sd|
LOGIT_BOUND = 12.0  # |logit| of mixture weights and discrete probabilities
Z_EPS = 1e-7  # uniform values are clipped into [a + eps, b - eps] before the logit


def select_columns(layout: dict[str, slice], feature_set: str) -> list[int]:
    """Column indices of a site's feature row used by the given feature set."""
    if feature_set not in FEATURE_GROUPS:
        raise ValueError(f"unknown feature set {feature_set!r} (one of {', '.join(FEATURE_SETS)})")
    cols: list[int] = []
    for group in FEATURE_GROUPS[feature_set]:
        if group not in layout:
            raise NgpmError(
                f"feature set {feature_set!r} reads the {group!r} group, which these traces "
                f"do not have (recorded by an older ngpm: record them again)"
            )
        sl = layout[group]
        cols.extend(range(sl.start, sl.stop))
    return cols


@dataclass
class NetSpec:
    """Everything needed to rebuild one site's network (shapes, not weights)."""

    site_index: int
    kind: str
    n_f: int  # width of the site's raw feature row
    cols: list[int] = field(default_factory=list)  # selected columns of that row
    K: int = 4  # mixture components (continuous sites)
    k: int = 2  # categories (categorical sites)
    hidden: int = 0

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown site kind {self.kind!r}")
        if self.cols and not self.hidden:
            self.hidden = max(MIN_HIDDEN, len(self.cols) // 2)
        if not self.cols:
            self.hidden = 0

    @property
    def site_kind(self) -> SiteKind:
        return KINDS[self.kind]

    @property
    def n_out(self) -> int:
        return self.site_kind.n_out(self.K, self.k)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> NetSpec:
        return cls(**d)


# the bound b of b * tanh(raw / b) of each role of output column (sitekinds.SiteKind.columns)
BOUNDS = {"logw": LOGIT_BOUND, "mean": MEAN_BOUND, "logsd": LOGSD_BOUND, "prob": LOGIT_BOUND}


def output_bounds(spec: NetSpec) -> np.ndarray:
    """Per output column, the bound b of its bounding transform (`SiteNet.heads`)."""
    return np.concatenate(
        [np.full(width, BOUNDS[role]) for role, width in spec.site_kind.columns(spec.K, spec.k)]
    )


def _bound(x: torch.Tensor, b: float) -> torch.Tensor:
    return b * torch.tanh(x * (1.0 / b))


def _unbound(y: float, b: float) -> float:
    return b * math.atanh(y / b)


class SiteNet(nn.Module):
    """One site's guide network; `forward` returns section-5 proposal parameters."""

    cols: torch.Tensor  # buffers (register_buffer)
    shift: torch.Tensor
    scale: torch.Tensor
    l1: nn.Linear | None
    l2: nn.Linear | None
    const: nn.Parameter | None

    def __init__(
        self,
        spec: NetSpec,
        mean: np.ndarray | None = None,
        std: np.ndarray | None = None,
        prior_probs: tuple[float, ...] | None = None,
        seed: int = 0,
    ) -> None:
        super().__init__()
        self.spec = spec
        n_in = len(spec.cols)
        mean = np.zeros(n_in) if mean is None else np.asarray(mean, dtype=np.float64)
        std = np.ones(n_in) if std is None else np.asarray(std, dtype=np.float64)
        std = np.where(np.isfinite(std) & (std > 1e-6), std, 1.0)
        self.register_buffer("cols", torch.tensor(spec.cols, dtype=torch.long))
        self.register_buffer("shift", torch.tensor(mean, dtype=torch.float32))
        self.register_buffer("scale", torch.tensor(1.0 / std, dtype=torch.float32))
        gen = torch.Generator().manual_seed(seed)
        bias = torch.tensor(self._prior_bias(prior_probs), dtype=torch.float32)
        if n_in:
            self.l1 = nn.Linear(n_in, spec.hidden)
            self.l2 = nn.Linear(spec.hidden, spec.n_out)
            with torch.no_grad():
                for layer, gain in ((self.l1, 1.0), (self.l2, 0.1)):
                    bound = gain / math.sqrt(layer.in_features)
                    layer.weight.copy_(
                        torch.empty_like(layer.weight).uniform_(-bound, bound, generator=gen)
                    )
                    layer.bias.zero_()
                self.l2.bias.copy_(bias)
            self.const = None
        else:
            self.l1 = self.l2 = None
            self.const = nn.Parameter(bias.clone())

    def _prior_bias(self, prior_probs: tuple[float, ...] | None) -> list[float]:
        """Raw outputs for which the network's proposal is close to the prior."""
        s = self.spec
        head = s.site_kind.head
        if head == MIXTURE:
            spread = np.linspace(-0.3, 0.3, s.K) if s.K > 1 else np.zeros(1)
            logsd0 = math.log(s.site_kind.z_sd0)
            means = [_unbound(float(m), MEAN_BOUND) for m in spread]
            return [0.0] * s.K + means + [_unbound(logsd0, LOGSD_BOUND)] * s.K
        if head == SIGMOID:  # prior_probs = (p,): probability of 1
            p1 = 0.5 if not prior_probs else float(np.clip(prior_probs[-1], 1e-4, 1 - 1e-4))
            return [_unbound(math.log(p1 / (1 - p1)), LOGIT_BOUND)]
        probs = np.full(s.k, 1.0 / s.k) if prior_probs is None else np.asarray(prior_probs, float)
        if len(probs) != s.k or not np.all(probs > 0):
            probs = np.full(s.k, 1.0 / s.k)
        probs = probs / probs.sum()
        logp = np.log(np.clip(probs, 1e-5, 1.0))
        return [_unbound(float(v - logp.mean()), LOGIT_BOUND) for v in logp]

    def raw(self, x: torch.Tensor) -> torch.Tensor:
        """Unbounded outputs `(n, n_out)` for raw feature rows `(n, n_f)`."""
        if self.l1 is None or self.l2 is None:
            assert self.const is not None
            return self.const.unsqueeze(0).expand(x.shape[0], -1)
        h = (x[:, self.cols] - self.shift) * self.scale
        out: torch.Tensor = self.l2(torch.tanh(self.l1(h)))
        return out

    def heads(self, raw: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Bounded outputs: (log weights, means, log sds) or (logits,)."""
        s = self.spec
        if s.site_kind.head == MIXTURE:
            K = s.K
            logw = torch.log_softmax(_bound(raw[:, :K], LOGIT_BOUND), dim=1)
            return logw, _bound(raw[:, K : 2 * K], MEAN_BOUND), _bound(raw[:, 2 * K :], LOGSD_BOUND)
        return (_bound(raw, LOGIT_BOUND),)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.heads(self.raw(x))
        head = self.spec.site_kind.head
        if head == MIXTURE:
            return torch.cat(out, dim=1)
        if head == SIGMOID:
            return torch.sigmoid(out[0])
        return torch.softmax(out[0], dim=1)

    def log_prob(self, x: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """log q of training targets `(n,)`: z for continuous sites (see `continuous_z`,
        without its Jacobian), 0/1 for bernoulli, the index for categorical."""
        out = self.heads(self.raw(x))
        head = self.spec.site_kind.head
        if head == MIXTURE:
            logw, mean, logsd = out
            z = target.unsqueeze(1)
            comp = (
                -0.5 * ((z - mean) * torch.exp(-logsd)) ** 2 - logsd - 0.5 * math.log(2 * math.pi)
            )
            return torch.logsumexp(logw + comp, dim=1)
        logits = out[0]
        if head == SIGMOID:
            t = target.to(logits.dtype)
            return -nn.functional.binary_cross_entropy_with_logits(
                logits[:, 0], t, reduction="none"
            )
        return torch.log_softmax(logits, dim=1).gather(1, target.long().unsqueeze(1))[:, 0]


def continuous_z(
    kind: str, values: np.ndarray, prior_args: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Map site values to the networks' target space and return (target, log Jacobian).

    normal (mu, sigma): z = (x - mu) / sigma, log q(x) = log q(z) - log sigma.
    uniform (a, b): z = logit((x - a) / (b - a)), log q(x) = log q(z) - log((b - a) u (1 - u)).
    bernoulli / categorical: the value itself (as an index), Jacobian 0.
    (The runtime's site-kind table, `SiteKind.to_z`, holds these maps.)
    """
    return KINDS[kind].to_z(np.asarray(values, dtype=np.float64), prior_args, Z_EPS)


GUIDE_FORMAT = "ngpm-guide-torch/1"


@dataclass
class GuideModel:
    """A trained (or untrained) set of site networks plus what export and the runtime check."""

    grammar: str
    grammar_hash: str
    sites: list[dict[str, Any]]  # the program's site table (Site.to_json rows)
    feature_set: str
    K: int
    nets: dict[int, SiteNet]
    layouts: dict[int, dict[str, list[int]]] = field(default_factory=dict)  # [start, stop]
    summary: dict[str, Any] = field(default_factory=dict)

    def state(self) -> dict[str, Any]:
        """Plain dict (tensors, lists, strings) for torch.save(weights_only=True).

        The tensors are copies: a state kept as the best epoch's must not change when
        training goes on."""
        return {
            "format": GUIDE_FORMAT,
            "grammar": self.grammar,
            "grammar_hash": self.grammar_hash,
            "sites": self.sites,
            "feature_set": self.feature_set,
            "K": self.K,
            "layouts": {str(i): v for i, v in self.layouts.items()},
            "summary": self.summary,
            "nets": {
                str(i): {
                    "spec": net.spec.to_json(),
                    "state": {k: v.detach().clone() for k, v in net.state_dict().items()},
                }
                for i, net in self.nets.items()
            },
        }

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> GuideModel:
        if d.get("format") != GUIDE_FORMAT:
            raise ValueError(f"not an ngpm guide model (format {d.get('format')!r})")
        nets: dict[int, SiteNet] = {}
        for key, item in d["nets"].items():
            net = SiteNet(NetSpec.from_json(item["spec"]))
            net.load_state_dict(item["state"])
            nets[int(key)] = net
        return cls(
            grammar=d["grammar"],
            grammar_hash=d["grammar_hash"],
            sites=d["sites"],
            feature_set=d["feature_set"],
            K=int(d["K"]),
            nets=nets,
            layouts={int(k): v for k, v in d["layouts"].items()},
            summary=d.get("summary", {}),
        )
