"""SMC into a 3D target stays exact: on a tiny compiled 3D grammar with discrete sites, the
posterior and evidence of SMC with the voxel likelihood (prior proposal, a fixed proposal,
and a proposal that reads the 3D features) match exact enumeration."""

from __future__ import annotations

import math

import numpy as np
import pytest
from fixtures.exact import check, exact, pooled, tv
from fixtures.volume3d import box_target
from ngpm_runtime.geometry.turtle3d import bounds3d
from ngpm_runtime.inference.distributions import prior_logpdf
from ngpm_runtime.inference.proposals import FixedProposal
from ngpm_runtime.inference.smc import SMCOptions, TraceRecording, smc
from ngpm_runtime.volume.likelihood import VoxelLikelihood
from ngpm_runtime.volume.raster import VoxelGrid, voxelize

TINY3D = """
dimensions: 3
viewport: -4 4 -1 7 -4 4
derivation length: 3
start: 0 0 90
Axiom: !(0.4) X(0)
production:
X(n) : n < 2 --> F(1) [ &(45 * categorical(1, 2, 1)) F(1 + flip(0.4)) ] /(90) X(n + 1) : 0.7
    | @O(0.6 + 0.8 * flip(0.5)) : 0.3
endlsystem
"""
GRID = VoxelGrid((-4.0, -1.0, -4.0), 1.0, (8, 8, 8))


class TotalVoxel(VoxelLikelihood):
    """The voxel likelihood with `total(prims)`, the from-scratch score `exact` needs."""

    def total(self, prims) -> float:
        vox = voxelize(list(prims), self.grid)
        return self.full(vox, np.array(bounds3d(list(prims)), dtype=float))


class WindowProposal:
    """A proposal that reads the 3D features: at the categorical site, weights from the
    target's and the canvas's window means, so the features decide the proposal (log q is
    the proposal's own, so SMC's weights must correct it)."""

    uses_features = True

    def propose(self, site, args, feats, rng):
        n = len(args)
        if site.kind != "categorical" or site.probs is not None:
            q = FixedProposal({site.index: [0.5] if site.kind == "bernoulli" else [0.3, 0.7]})
            return q.propose(site, args, feats, rng)
        assert feats is not None and feats.shape[1] == 14 + 1 + 3 + 2 * 27 * 4
        lean = np.clip(feats[:, 18:126].mean(axis=1) - feats[:, 126:].mean(axis=1), -1, 1)
        p = np.stack([0.2 + 0.2 * lean, 0.3 - 0.1 * lean, 0.5 - 0.1 * lean], axis=1)
        p /= p.sum(axis=1, keepdims=True)
        cum = p.cumsum(axis=1)
        v = (rng.random(n)[:, None] > cum).sum(axis=1).astype(float)
        return v, np.log(p[np.arange(n), v.astype(int)])


@pytest.fixture(scope="module")
def tiny3d():
    from ngpm_compiler.language.compile import compile_grammar

    prog = compile_grammar(TINY3D, filename="tiny3d.lsys").program()
    assert prog.dim == 3 and prog.box == (-4, 4, -1, 7, -4, 4)
    return prog


@pytest.fixture(scope="module")
def like():
    target = box_target(GRID, (-1.0, -1.0, -1.0), (1.0, 3.0, 1.0))
    target.occupancy[3:6, 3:5, 3:5] = True  # and a bulge, so that branches matter
    return TotalVoxel(target, (-4, 4, -1, 7, -4, 4), sigma=0.5)


def test_enumeration_spreads_over_many_derivations(tiny3d, like) -> None:
    post, log_z = exact(tiny3d, like)
    assert len(post) > 20 and max(post.values()) < 0.5 and math.isfinite(log_z)


@pytest.mark.parametrize(
    ("scheme", "ess", "prop"),
    [("residual", None, None), ("systematic", 0.5, "fixed"), ("stratified", None, "windows")],
)
def test_smc_into_a_volume_matches_enumeration(tiny3d, like, scheme, ess, prop) -> None:
    want_post, want_log_z = exact(tiny3d, like)
    q = {
        None: None,
        "fixed": FixedProposal({0: [0.4, 0.6], 1: [0.5, 0.2, 0.3], 2: [0.7], 3: [0.2]}),
        "windows": WindowProposal(),
    }[prop]
    post, log_z = pooled(tiny3d, like, q, scheme, ess, seed=40)
    assert check(post, log_z, want_post, want_log_z, 0.08), (tv(post, want_post), log_z, want_log_z)


def test_the_check_notices_a_proposal_whose_weights_are_ignored(tiny3d, like) -> None:
    class Unweighted(WindowProposal):
        def propose(self, site, args, feats, rng):
            v, _ = super().propose(site, args, feats, rng)
            return v, prior_logpdf(site, args, v)

    want_post, want_log_z = exact(tiny3d, like)
    post, log_z = pooled(tiny3d, like, Unweighted(), "residual", None, n=2000, runs=3)
    assert not check(post, log_z, want_post, want_log_z, 0.08)


def test_full_traces_carry_3d_feature_rows_that_replay_gives_again(tiny3d, like) -> None:
    from ngpm_runtime.inference.smc import replay
    from ngpm_runtime.volume.features import FeatureMaker3D

    fm = FeatureMaker3D(tiny3d, GRID, like.source)
    r = smc(tiny3d, like, 20, options=SMCOptions(seed=2, trace=TraceRecording.FULL))
    best = r.best
    assert best.trace
    for s, f, _ in best.trace:  # the likelihood's target is what the windows read
        assert f is not None and f.dtype == np.float32
        assert f.shape == (fm.n_features(tiny3d.sites[s]),)
    again = replay(tiny3d, [(s, v) for s, _, v in best.trace], volume=like.source)
    assert again.primitives == best.primitives
    for (s1, f1, v1), (s2, f2, v2) in zip(best.trace, again.trace or [], strict=True):
        assert (s1, v1) == (s2, v2)
        np.testing.assert_array_equal(f1, f2)
    target_cols = f1[fm.layout(tiny3d.sites[s1])["target"]]
    assert (target_cols == 1.0).any() and (target_cols == 0.0).any()
