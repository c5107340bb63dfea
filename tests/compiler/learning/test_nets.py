"""Guide networks: output formats, near-prior initialization, normalized densities."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ngpm_compiler.learning.nets import NetSpec, SiteNet, continuous_z, select_columns

LAYOUT = {"local": slice(0, 4), "target": slice(4, 10), "partial": slice(10, 16)}


def make_net(
    kind: str,
    K: int = 4,
    feature_set: str = "all",
    k: int = 3,
    probs: tuple[float, ...] | None = None,
) -> SiteNet:
    spec = NetSpec(
        site_index=0, kind=kind, n_f=16, cols=select_columns(LAYOUT, feature_set), K=K, k=k
    )
    return SiteNet(spec, prior_probs=probs)


def test_select_columns_and_hidden_size():
    assert select_columns(LAYOUT, "const") == []
    assert select_columns(LAYOUT, "local") == [0, 1, 2, 3]
    assert select_columns(LAYOUT, "local+target") == list(range(10))
    assert select_columns(LAYOUT, "all") == list(range(16))
    with pytest.raises(ValueError):
        select_columns(LAYOUT, "everything")
    assert make_net("normal", feature_set="all").spec.hidden == 8  # 16 / 2
    assert make_net("normal", feature_set="local").spec.hidden == 8  # the minimum
    spec = NetSpec(site_index=0, kind="normal", n_f=76, cols=list(range(76)))
    assert spec.hidden == 38 and spec.n_out == 12


@pytest.mark.parametrize("feature_set", ["const", "all"])
def test_untrained_is_close_to_prior(feature_set):
    torch.manual_seed(0)
    x = torch.randn(200, 16) * 2
    out = make_net("normal", feature_set=feature_set)(x)
    assert out.shape == (200, 12)
    w, m, s = torch.exp(out[:, :4]), out[:, 4:8], out[:, 8:]
    assert torch.allclose(w.sum(1), torch.ones(200), atol=1e-5)
    assert (w - 0.25).abs().max() < 0.1 and m.abs().max() < 0.6 and s.abs().max() < 0.2
    p = make_net("bernoulli", feature_set=feature_set)(x)
    assert p.shape == (200, 1) and (p - 0.5).abs().max() < 0.1
    q = make_net("categorical", feature_set=feature_set, probs=(0.2, 0.3, 0.5))(x)
    assert q.shape == (200, 3)
    assert (q - torch.tensor([0.2, 0.3, 0.5])).abs().max() < 0.1
    u = make_net("uniform", K=1, feature_set=feature_set)(x)
    assert u.shape == (200, 3) and (u[:, 2] - math.log(1.7)).abs().max() < 0.2


@pytest.mark.parametrize("kind", ["normal", "uniform"])
@pytest.mark.parametrize("K", [1, 4])
def test_continuous_density_integrates_to_one(kind, K):
    torch.manual_seed(1)
    net = make_net(kind, K=K)
    with torch.no_grad():
        for p in net.parameters():
            p.add_(torch.randn_like(p) * 0.3)
    x = torch.randn(1, 16).expand(4001, 16)
    if kind == "normal":
        values = np.linspace(-80, 80, 4001)
        args = np.tile([3.0, 2.0], (4001, 1))
        dvalues = np.gradient(values)
    else:  # integrate over z (the density piles up at the edges), dx = (dx/dz) dz
        zgrid = np.linspace(-60, 60, 4001)
        values = -1 + 3 / (1 + np.exp(-zgrid))
        args = np.tile([-1.0, 2.0], (4001, 1))
        dvalues = np.gradient(values, zgrid) * np.gradient(zgrid)
    z, jac = continuous_z(kind, values, args)
    keep = np.isfinite(z) & (np.abs(z) < 15)  # u clipped to [1e-7, 1 - 1e-7]
    with torch.no_grad():
        logq = net.log_prob(x, torch.tensor(z, dtype=torch.float32)).double().numpy() + jac
    integral = np.sum(np.exp(logq[keep]) * dvalues[keep])
    assert integral == pytest.approx(1.0, abs=0.02)


def test_discrete_log_prob_matches_forward():
    torch.manual_seed(2)
    x = torch.randn(50, 16)
    net = make_net("categorical", k=3)
    with torch.no_grad():
        for p in net.parameters():
            p.add_(torch.randn_like(p))
        probs = net(x)
        for c in range(3):
            lp = net.log_prob(x, torch.full((50,), float(c)))
            assert torch.allclose(lp.exp(), probs[:, c], atol=1e-6)
    net = make_net("bernoulli")
    with torch.no_grad():
        for p in net.parameters():
            p.add_(torch.randn_like(p))
        p1 = net(x)[:, 0]
        assert torch.allclose(net.log_prob(x, torch.ones(50)).exp(), p1, atol=1e-6)
        assert torch.allclose(net.log_prob(x, torch.zeros(50)).exp(), 1 - p1, atol=1e-6)


def test_outputs_are_bounded():
    net = make_net("normal", K=4)
    with torch.no_grad():
        for p in net.parameters():
            p.mul_(1000)
        out = net(torch.randn(100, 16) * 1000)
    assert torch.isfinite(out).all()
    assert out[:, 4:8].abs().max() <= 10.0 + 1e-4 and out[:, 8:].abs().max() <= 5.0 + 1e-4
    assert out[:, :4].min() > -30
