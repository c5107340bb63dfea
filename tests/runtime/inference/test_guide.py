"""runtime Guide: the Proposal protocol, prior fallback, one onnxruntime call per site per
round; and the CLI pipeline traces -> train -> export -> grow on a small grammar."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fixtures.datasets import CHAIN, make_dataset
from fixtures.guides import N_F, SITES, fake_program, random_model
from ngpm_runtime.inference.distributions import prior_logpdf, proposal_logpdf
from ngpm_runtime.inference.guide import Guide
from ngpm_runtime.inference.smc import SMCOptions, smc
from reference.guide import numpy_forward

from ngpm_compiler.cli import main
from ngpm_compiler.learning.export import write_onnx


class CountingSession:
    def __init__(self, session, calls=None):
        self.session = session
        self.calls = [] if calls is None else calls

    def run(self, names, feeds):
        self.calls.append(names)
        return self.session.run(names, feeds)


def count_calls(g: Guide) -> None:
    """Count onnxruntime calls of the whole-file and per-site sessions in g.session.calls
    (the numpy engine switched off)."""
    g.numpy_nets = {}
    g.session = CountingSession(g.session)
    g.site_sessions = {s: CountingSession(x, g.session.calls) for s, x in g.site_sessions.items()}


@pytest.fixture()
def guide(tmp_path):
    path = write_onnx(random_model(4, "all", skip=(2,)), tmp_path / "g.onnx")
    g = Guide.load(path, fake_program())
    count_calls(g)
    return g


def test_propose_matches_proposal_density(guide):
    rng = np.random.default_rng(0)
    feats = rng.normal(size=(4000, N_F)).astype(np.float32)
    feats[:] = feats[0]  # one feature row: the samples follow one mixture
    for site, args in ((SITES[0], [2.0, 3.0]), (SITES[1], [-1.0, 4.0]), (SITES[3], [1, 1, 1])):
        a = np.tile(np.array(args, float), (4000, 1))
        values, log_q = guide.propose(site, a, feats, rng)
        params = guide.params(site.index, feats[:1])
        assert np.allclose(log_q, proposal_logpdf(site, a, np.repeat(params, 4000, 0), values))
        if site.kind == "categorical":
            freq = np.bincount(values.astype(int), minlength=3) / 4000
            assert np.abs(freq - params[0]).max() < 0.03
        else:  # the sample's histogram matches the density
            lo, hi = np.quantile(values, [0.25, 0.75])
            grid = np.linspace(lo, hi, 2001)
            dens = np.exp(proposal_logpdf(site, a[:2001], np.repeat(params, 2001, 0), grid))
            mass = float(np.sum((dens[1:] + dens[:-1]) / 2 * np.diff(grid)))
            assert mass == pytest.approx(0.5, abs=0.03)
    assert len(guide.session.calls) == 3 + 3  # one call per propose (+ params checks)


def test_site_sessions_match_the_whole_file(tmp_path):
    """Per-site sessions cut from the file give the whole file's outputs, bit for bit; without
    them (no `onnx` package) the whole-file session answers."""
    path = write_onnx(random_model(4, "all", skip=(2,)), tmp_path / "g.onnx")
    g = Guide.load(path, fake_program())
    assert sorted(g.site_sessions) == sorted(g.nets) and 2 not in g.site_sessions
    feats = np.random.default_rng(2).normal(size=(5, N_F)).astype(np.float32)
    g.numpy_nets = {}
    for s in g.nets:
        split = g.params(s, feats)
        whole = Guide.load(path, fake_program())
        whole.site_sessions = whole.numpy_nets = {}
        np.testing.assert_array_equal(split, whole.params(s, feats))


@pytest.mark.parametrize("K, feature_set", [(4, "all"), (1, "local"), (3, "all")])
def test_numpy_nets_match_onnxruntime(tmp_path, K, feature_set):
    """The numpy engine (the file's weights) gives onnxruntime's parameters to 1e-5, for
    every head (mixture, bernoulli, categorical) and batch size."""
    path = write_onnx(random_model(K, feature_set, seed=K), tmp_path / "g.onnx")
    g = Guide.load(path, fake_program())
    assert sorted(g.numpy_nets) == sorted(g.nets)
    rng = np.random.default_rng(4)
    for s in g.nets:
        for n in (1, 3, 10, 300):
            x = (rng.normal(size=(n, N_F)) * 3).astype(np.float32)
            (want,) = g.site_sessions[s].run(None, {f"f_{s}": x})
            got = g.params(s, x)
            assert got.dtype == np.float64 and got.shape == want.shape
            np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)


def test_bundled_guide_engines_agree():
    """The bundled guide: every network runs in numpy (its weights read by name) and gives
    onnxruntime's outputs (the site's own session) to 1e-5, for batches of 1 to 500 rows
    of feature-like and of wilder numbers."""
    from ngpm_runtime import bundled
    from ngpm_runtime.inference.guide_format import input_name

    g = bundled.bundled_guide()
    assert len(g.nets) == 8 and [g.engine(s) for s in g.nets] == ["numpy"] * 8
    rng = np.random.default_rng(8)
    for s, net in g.nets.items():
        for n, scale in ((1, 1.0), (4, 3.0), (50, 1.0), (500, 0.5)):
            x = (rng.uniform(-1, 1, size=(n, net["n_f"])) * scale).astype(np.float32)
            (want,) = g.site_sessions[s].run(None, {input_name(s): x})
            got = g.numpy_nets[s](x)
            np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
            # the numpy code the kernel replaced (tests/reference/guide.py)
            np.testing.assert_allclose(got, numpy_forward(g.numpy_nets[s], x), rtol=1e-5, atol=1e-6)


def test_numpy_nets_batch_equals_rows_alone():
    """The kernel's networks run four rows of a site at a time, then two, then one; every
    row's parameters are bit for bit those of the row alone (the bundled guide, every
    site, batches of 1 to 11 rows)."""
    from ngpm_runtime import bundled

    g = bundled.bundled_guide()
    rng = np.random.default_rng(11)
    for s, net in g.nets.items():
        for n in (1, 2, 3, 4, 5, 7, 11):
            x = rng.uniform(-1, 1, size=(n, net["n_f"])).astype(np.float32)
            got = g.numpy_nets[s](x)
            want = np.concatenate([g.numpy_nets[s](x[k : k + 1]) for k in range(n)])
            np.testing.assert_array_equal(got, want)


def test_engine_names_the_path(tmp_path):
    """Guide.engine: numpy for a net that reads features, onnxruntime for a feature-free
    one, the prior for a site without a net; emptying numpy_nets switches to onnxruntime."""
    g = Guide.load(
        write_onnx(random_model(2, "all", skip=(2,)), tmp_path / "g.onnx"), fake_program()
    )
    assert [g.engine(s) for s in range(4)] == ["numpy", "numpy", "prior", "numpy"]
    g.numpy_nets = {}
    assert g.engine(0) == "onnxruntime"
    c = Guide.load(write_onnx(random_model(2, "const"), tmp_path / "c.onnx"), fake_program())
    assert c.engine(0) == "onnxruntime"


def test_const_guide_runs_in_onnxruntime(tmp_path):
    """A graph of another form (the const nets' Expand) gets no numpy engine."""
    g = Guide.load(write_onnx(random_model(2, "const"), tmp_path / "c.onnx"), fake_program())
    assert g.numpy_nets == {}


def test_propose_round_matches_propose(tmp_path):
    """propose_round: per site, values with log q = proposal_logpdf under the site's own
    parameters; fallback sites use the prior; seeded calls repeat exactly."""
    path = write_onnx(random_model(4, "all", skip=(2,)), tmp_path / "g.onnx")
    g = Guide.load(path, fake_program())
    rng = np.random.default_rng(6)
    sites = [SITES[0], SITES[1], SITES[2], SITES[3]]
    ns = [5, 1, 4, 7]
    args = [
        np.tile([2.0, 3.0], (5, 1)),
        np.tile([-1.0, 4.0], (1, 1)),
        np.full((4, 1), 0.3),
        np.tile([1.0, 1.0, 1.0], (7, 1)),
    ]
    feats = [rng.normal(size=(n, N_F)).astype(np.float32) for n in ns]
    a = g.propose_round(sites, args, feats, np.random.default_rng(1))
    b = g.propose_round(sites, args, feats, np.random.default_rng(1))
    for site, n, arg, f, (v, q, *lp), (v2, q2, *_) in zip(
        sites, ns, args, feats, a, b, strict=True
    ):
        assert v.shape == q.shape == (n,)
        np.testing.assert_array_equal(v, v2)
        np.testing.assert_array_equal(q, q2)
        if site.index in g.nets:
            want = proposal_logpdf(site, arg, g.params(site.index, f), v)
            # the kernel's log prior, drawn with the values
            np.testing.assert_allclose(lp[0], prior_logpdf(site, arg, v), rtol=1e-12)
        else:
            want = prior_logpdf(site, arg, v)
        np.testing.assert_allclose(q, want, rtol=1e-12, atol=1e-12)


def test_propose_round_engines_agree(tmp_path):
    """A round served by onnxruntime (per-site sessions, or the whole file as without the
    `onnx` package) draws what the kernel's own nets draw from the same generator: the
    same values and log q to float32 rounding, log prior alike."""
    path = write_onnx(random_model(4, "all", skip=(2,)), tmp_path / "g.onnx")
    rng = np.random.default_rng(16)
    sites = [SITES[0], SITES[1], SITES[2], SITES[3]]
    args = [
        np.tile([2.0, 3.0], (6, 1)),
        np.tile([-1.0, 4.0], (2, 1)),
        np.full((4, 1), 0.3),
        np.tile([1.0, 2.0, 1.0], (5, 1)),
    ]
    feats = [rng.normal(size=(len(a), N_F)).astype(np.float32) for a in args]
    kernel = Guide.load(path, fake_program())
    split = Guide.load(path, fake_program())
    split.numpy_nets = {}
    whole = Guide.load(path, fake_program())
    whole.site_sessions = whole.numpy_nets = {}
    want = kernel.propose_round(sites, args, feats, np.random.default_rng(3))
    for g in (split, whole):
        got = g.propose_round(sites, args, feats, np.random.default_rng(3))
        for a, b in zip(got, want, strict=True):
            assert len(a) == len(b)
            for x, y in zip(a, b, strict=True):
                np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-5)


def test_propose_round_of_one_site_equals_propose(tmp_path):
    """A round of one site (propose_round's short path) draws what propose draws, bit for
    bit, for a site with a net and for a fallback site."""
    path = write_onnx(random_model(4, "all", skip=(2,)), tmp_path / "g.onnx")
    g = Guide.load(path, fake_program())
    rng = np.random.default_rng(7)
    for site, arg in (
        (SITES[0], np.tile([2.0, 3.0], (5, 1))),
        (SITES[2], np.full((5, 1), 0.3)),
        (SITES[3], np.tile([1.0, 1.0, 1.0], (5, 1))),
    ):
        f = rng.normal(size=(5, N_F)).astype(np.float32)
        ((v, q, *_),) = g.propose_round([site], [arg], [f], np.random.default_rng(2))
        v2, q2 = g.propose(site, arg, f, np.random.default_rng(2))
        np.testing.assert_array_equal(v, v2)
        np.testing.assert_array_equal(q, q2)


def test_fallback_site_uses_the_prior(guide):
    rng = np.random.default_rng(1)
    site = SITES[2]
    args = np.full((1000, 1), 0.3)
    values, log_q = guide.propose(site, args, np.zeros((1000, N_F), np.float32), rng)
    assert np.allclose(log_q, prior_logpdf(site, args, values))
    assert abs(values.mean() - 0.3) < 0.05
    assert guide.session.calls == [] and guide.fallback_sites == [2]


def test_const_guide_needs_no_features(tmp_path):
    g = Guide.load(write_onnx(random_model(1, "const"), tmp_path / "c.onnx"), fake_program())
    assert not g.uses_features
    values, log_q = g.propose(SITES[0], np.tile([0.0, 1.0], (5, 1)), None, np.random.default_rng(0))
    assert values.shape == log_q.shape == (5,) and np.isfinite(log_q).all()


def test_one_call_per_site_per_round_in_smc(tmp_path):
    """Run SMC with a guide on the chain grammar and count onnxruntime calls."""
    from ngpm_compiler.language.compile import load_grammar

    program = load_grammar(CHAIN)
    out = tmp_path / "m"
    data = make_dataset(tmp_path / "data", 2)
    assert (
        main(
            [
                "traces",
                CHAIN,
                "--targets",
                str(data),
                "-n",
                "3",
                "--particles",
                "5",
                "-o",
                str(out / "tr"),
                "--workers",
                "1",
            ]
        )
        == 0
    )
    assert main(["train", str(out / "tr"), "-o", str(out / "m.pt"), "--epochs", "2"]) == 0
    assert main(["export", str(out / "m.pt"), "-o", str(out / "g.onnx")]) == 0
    g = Guide.load(out / "g.onnx", program)
    count_calls(g)
    r = smc(program, None, 7, g, options=SMCOptions(ess_from_proposal=True, seed=0))
    assert all(len(p.primitives) == 12 for p in r.particles)
    assert len(g.session.calls) == 12  # one site, one round per chain link, all 7 particles


def test_cli_pipeline_and_errors(tmp_path, capsys):
    data = make_dataset(tmp_path / "data", 2)
    tr, model, onnx_path = tmp_path / "tr", tmp_path / "m.pt", tmp_path / "g.onnx"
    assert (
        main(
            [
                "traces",
                CHAIN,
                "--targets",
                str(data),
                "-n",
                "4",
                "--particles",
                "6",
                "-o",
                str(tr),
                "--workers",
                "1",
                "--mirror",
            ]
        )
        == 0
    )
    out, err = capsys.readouterr()
    assert "4 traces kept" in out
    assert "\r" not in err and err.count("\n") <= 2, err  # no progress bar in a log file
    assert (
        main(
            ["train", str(tr), "-o", str(model), "--epochs", "3", "--K", "1", "--features", "local"]
        )
        == 0
    )
    out, err = capsys.readouterr()
    assert "1 site networks" in out and "validation NLL" in out
    assert "\r" not in err and err.count("\n") <= 2, err
    assert not Path(str(model) + ".ckpt").exists()
    assert main(["export", str(model), "-o", str(onnx_path)]) == 0
    png = tmp_path / "grown.png"
    assert (
        main(
            [
                "grow",
                str(data / "bar0.png"),
                "--grammar",
                CHAIN,
                "--guide",
                str(onnx_path),
                "-N",
                "5",
                "-o",
                str(png),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "similarity" in out and "(guided)" in out and png.is_file()
    assert (
        main(["grow", str(data / "bar0.png"), "--grammar", CHAIN, "-N", "5", "-o", str(png)]) == 0
    )
    assert "(unguided)" in capsys.readouterr().out
    # a guide for another grammar, a corrupt guide, a corrupt model: one-line errors
    vines = str(Path(CHAIN).with_name("vines.lsys"))
    assert (
        main(
            [
                "grow",
                str(data / "bar0.png"),
                "--grammar",
                vines,
                "--guide",
                str(onnx_path),
                "-o",
                str(png),
            ]
        )
        == 1
    )
    assert "trained for grammar" in capsys.readouterr().err
    onnx_path.write_bytes(onnx_path.read_bytes()[:100])
    assert (
        main(
            [
                "grow",
                str(data / "bar0.png"),
                "--grammar",
                CHAIN,
                "--guide",
                str(onnx_path),
                "-o",
                str(png),
            ]
        )
        == 1
    )
    assert "corrupt or truncated" in capsys.readouterr().err
    model.write_bytes(b"junk")
    assert main(["export", str(model), "-o", str(onnx_path)]) == 1
    err = capsys.readouterr().err
    assert "not a model written by" in err and err.count("\n") == 1
