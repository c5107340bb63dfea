"""Training: the guide approaches known conditionals (KL falls), held-out jobs, resume."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from ngpm_runtime.program import Site
from scipy.special import expit, softmax

from ngpm_compiler.learning.trace_data import JOB_STRIDE
from ngpm_compiler.learning.train import (
    SiteData,
    TrainConfig,
    _nll,
    _splits,
    load_model,
    save_model,
    split_jobs,
    train_guide,
    weights_hash,
)

SITES = [
    Site(index=0, id="A/0/normal0", kind="normal"),
    Site(index=1, id="A/0/uniform0", kind="uniform"),
    Site(index=2, id="A/0/bernoulli0", kind="bernoulli"),
    Site(index=3, id="A/choice", kind="categorical", k=3, probs=(1 / 3, 1 / 3, 1 / 3)),
    Site(index=4, id="A/0/normal1", kind="normal"),  # never visited: no network
]
# features: [x, noise, prior args...]; local = everything, no image groups
LAYOUTS = {
    s.index: {"local": slice(0, 2 + s.n_args()), "target": slice(2, 2), "partial": slice(2, 2)}
    for s in SITES
}


def synthetic(n_jobs: int, per_job: int, seed: int) -> tuple[dict[int, SiteData], dict]:
    """Site visits whose values depend on feature x in known ways; returns data and the true
    log densities of the values (for KL = NLL_model - NLL_true)."""
    rng = np.random.default_rng(seed)
    m = n_jobs * per_job
    jobs = np.repeat(np.arange(n_jobs), per_job)
    x = rng.uniform(-1, 1, m)
    noise = rng.normal(size=m)
    data, true_logp = {}, {}
    # normal: mu = 5, sigma = 2; in prior units z ~ 0.5 N(2x, 0.3) + 0.5 N(-1.5, 0.2)
    comp = rng.random(m) < 0.5
    z = np.where(comp, rng.normal(2 * x, 0.3), rng.normal(-1.5, 0.2, m))
    args = np.tile([5.0, 2.0], (m, 1))
    lz = np.logaddexp(
        np.log(0.5) - 0.5 * ((z - 2 * x) / 0.3) ** 2 - np.log(0.3),
        np.log(0.5) - 0.5 * ((z + 1.5) / 0.2) ** 2 - np.log(0.2),
    )
    data[0] = (5 + 2 * z, args)
    true_logp[0] = lz - 0.5 * np.log(2 * np.pi) - np.log(2.0)
    # uniform on (0, 10): logit(u) ~ N(2x, 0.5)
    zu = rng.normal(2 * x, 0.5)
    u = expit(zu)
    data[1] = (10 * u, np.tile([0.0, 10.0], (m, 1)))
    true_logp[1] = (
        -0.5 * ((zu - 2 * x) / 0.5) ** 2
        - np.log(0.5)
        - 0.5 * np.log(2 * np.pi)
        - np.log(10 * u * (1 - u))
    )
    # bernoulli p = sigmoid(3x)
    p = expit(3 * x)
    b = (rng.random(m) < p).astype(float)
    data[2] = (b, np.full((m, 1), 0.5))
    true_logp[2] = np.log(np.where(b == 1, p, 1 - p))
    # categorical: softmax(3x, -3x, 0)
    probs = softmax(np.stack([3 * x, -3 * x, 0 * x], 1), axis=1)
    c = np.array([rng.choice(3, p=row) for row in probs], dtype=float)
    data[3] = (c, np.full((m, 3), 1 / 3))
    true_logp[3] = np.log(probs[np.arange(m), c.astype(int)])
    out = {}
    for i, (values, prior_args) in data.items():
        feats = np.column_stack([x, noise, prior_args]).astype(np.float32)
        out[i] = SiteData(feats, values, prior_args, jobs)
    return out, true_logp


def kl_per_visit(model, data, true_logp) -> dict[int, float]:
    kl = {}
    for i, net in model.nets.items():
        rows = np.arange(len(data[i].values))
        nll = _nll(net, _splits(SITES[i], data[i], rows))
        kl[i] = (nll + true_logp[i].sum()) / len(rows)
    return kl


def test_kl_falls_towards_known_conditionals():
    torch.manual_seed(0)
    data, _ = synthetic(n_jobs=40, per_job=100, seed=0)
    test, true_logp = synthetic(n_jobs=10, per_job=200, seed=1)
    config = TrainConfig(feature_set="local", K=4, epochs=25, batch_size=128, lr=0.01)
    untrained = train_guide(SITES, LAYOUTS, data, TrainConfig(**{**config.__dict__, "epochs": 0}))
    model = train_guide(SITES, LAYOUTS, data, config)
    before, after = kl_per_visit(untrained, test, true_logp), kl_per_visit(model, test, true_logp)
    assert sorted(model.nets) == [0, 1, 2, 3]  # site 4 never visited
    for i in range(4):
        assert after[i] < 0.5 * before[i], (i, before, after)
        assert after[i] < 0.1, (i, after)
    hist = model.summary["history"]
    assert hist[-1]["val_nll"] < hist[0]["val_nll"]
    assert model.summary["val_traces"] == 4 and model.summary["traces"] == 40


def test_const_features_learn_the_marginal():
    data, _ = synthetic(n_jobs=20, per_job=100, seed=3)
    model = train_guide(SITES, LAYOUTS, data, TrainConfig(feature_set="const", epochs=15, lr=0.02))
    with torch.no_grad():
        p = model.nets[2](torch.zeros(1, 3))[0, 0].item()
    assert p == pytest.approx(data[2].values.mean(), abs=0.05)


def test_hidden_width_is_a_setting():
    data, _ = synthetic(n_jobs=10, per_job=20, seed=4)
    auto = train_guide(SITES, LAYOUTS, data, TrainConfig(epochs=1))
    wide = train_guide(SITES, LAYOUTS, data, TrainConfig(epochs=1, hidden=24))
    for i, net in wide.nets.items():
        assert net.spec.hidden == 24 and net.l1.out_features == 24
        assert auto.nets[i].spec.hidden == max(8, len(auto.nets[i].spec.cols) // 2)


def test_holdout_is_by_job():
    jobs = np.repeat(np.arange(50), 7)
    val = split_jobs(jobs, 0.1, seed=0)
    assert len(val) == 5 and len(np.unique(val)) == 5
    assert np.array_equal(val, split_jobs(jobs, 0.1, seed=0))
    assert len(split_jobs(np.zeros(9, int), 0.1, 0)) == 0


def test_a_directorys_holdout_stays_when_more_directories_join():
    one = np.repeat(np.arange(40), 3)
    two = np.concatenate([one, np.repeat(np.arange(30) + JOB_STRIDE, 3)])
    val1, val2 = split_jobs(one, 0.1, seed=7), split_jobs(two, 0.1, seed=7)
    assert np.array_equal(val2[val2 < JOB_STRIDE], val1)
    assert (val2 >= JOB_STRIDE).sum() == 3  # a tenth of the second directory's 30


def test_warm_start_begins_where_the_earlier_model_ended():
    data, _ = synthetic(n_jobs=30, per_job=20, seed=8)
    cfg = dict(feature_set="local", K=2, batch_size=64, patience=100)
    first = train_guide(SITES, LAYOUTS, data, TrainConfig(epochs=6, **cfg))
    cold = train_guide(SITES, LAYOUTS, data, TrainConfig(epochs=1, **cfg))
    warm = train_guide(SITES, LAYOUTS, data, TrainConfig(epochs=1, **cfg), init=first)
    assert warm.summary["warm_started"] == sorted(first.nets)
    assert cold.summary["warm_started"] == []
    # one more epoch from the trained weights beats one epoch from scratch
    assert warm.summary["val_nll"] < cold.summary["val_nll"] - 1.0
    # a network of another shape is not copied
    wide = train_guide(SITES, LAYOUTS, data, TrainConfig(epochs=1, hidden=24, **cfg), init=first)
    assert wide.summary["warm_started"] == []


def test_a_checkpoint_of_another_initial_model_is_not_resumed(tmp_path):
    data, _ = synthetic(n_jobs=10, per_job=30, seed=2)
    cfg = dict(feature_set="local", K=2, batch_size=64, patience=100)
    a = train_guide(SITES, LAYOUTS, data, TrainConfig(epochs=2, seed=1, **cfg))
    b = train_guide(SITES, LAYOUTS, data, TrainConfig(epochs=2, seed=2, **cfg))
    assert weights_hash(a) != weights_hash(b)
    ck = tmp_path / "m.pt.ckpt"
    train_guide(SITES, LAYOUTS, data, TrainConfig(epochs=2, **cfg), checkpoint=ck, init=a)
    again = train_guide(SITES, LAYOUTS, data, TrainConfig(epochs=2, **cfg), checkpoint=ck, init=b)
    fresh = train_guide(SITES, LAYOUTS, data, TrainConfig(epochs=2, **cfg), init=b)
    assert_same_weights(again, fresh)


def test_checkpoint_resume_gives_the_same_model(tmp_path):
    data, _ = synthetic(n_jobs=10, per_job=30, seed=2)
    cfg = dict(feature_set="local", K=2, batch_size=64, patience=100)
    full = train_guide(SITES, LAYOUTS, data, TrainConfig(epochs=4, **cfg))
    ck = tmp_path / "m.pt.ckpt"
    train_guide(SITES, LAYOUTS, data, TrainConfig(epochs=2, **cfg), checkpoint=ck)
    assert ck.is_file()
    resumed = train_guide(SITES, LAYOUTS, data, TrainConfig(epochs=4, **cfg), checkpoint=ck)
    assert [h["val_nll"] for h in resumed.summary["history"]] == [
        h["val_nll"] for h in full.summary["history"]
    ]
    assert_same_weights(full, resumed)
    save_model(resumed, tmp_path / "m.pt")
    again = load_model(tmp_path / "m.pt")
    assert again.summary == resumed.summary and sorted(again.nets) == sorted(resumed.nets)


# a setting whose validation NLL rises before early stopping ends the run
EARLY = dict(feature_set="local", K=2, batch_size=16, lr=0.05, patience=2, epochs=30)


def val_nll_of(model, data, config) -> float:
    """The validation NLL per held-out trace of `model`, computed afresh from its weights."""
    all_jobs = np.concatenate([d.jobs for d in data.values()])
    val_jobs = split_jobs(all_jobs, config.val_fraction, config.seed)
    total = 0.0
    for i, net in model.nets.items():
        rows = np.flatnonzero(np.isin(data[i].jobs, val_jobs))
        total += _nll(net, _splits(SITES[i], data[i], rows))
    return total / len(val_jobs)


def test_early_stopping_returns_the_best_epochs_weights():
    data, _ = synthetic(n_jobs=12, per_job=15, seed=5)
    config = TrainConfig(**EARLY)
    model = train_guide(SITES, LAYOUTS, data, config)
    s = model.summary
    assert s["best_epoch"] < s["epochs_run"], s["history"]  # it did stop early
    assert s["val_nll"] == min(h["val_nll"] for h in s["history"])
    assert val_nll_of(model, data, config) == pytest.approx(s["val_nll"], rel=1e-5)


def assert_same_weights(a, b) -> None:
    assert sorted(a.nets) == sorted(b.nets)
    for i in a.nets:
        for (name, x), y in zip(
            a.nets[i].state_dict().items(), b.nets[i].state_dict().values(), strict=True
        ):
            assert torch.equal(x, y), (i, name)


def test_a_run_killed_after_any_epoch_resumes_to_the_uninterrupted_result(tmp_path):
    data, _ = synthetic(n_jobs=12, per_job=15, seed=5)
    config = TrainConfig(**EARLY)
    full = train_guide(SITES, LAYOUTS, data, config)
    for kill_at in range(1, full.summary["epochs_run"] + 1):
        ck = tmp_path / f"kill{kill_at}.ckpt"

        def kill(row, kill_at=kill_at):
            if row["epoch"] == kill_at:
                raise KeyboardInterrupt

        with pytest.raises(KeyboardInterrupt):
            train_guide(SITES, LAYOUTS, data, config, checkpoint=ck, on_epoch=kill)
        resumed = train_guide(SITES, LAYOUTS, data, config, checkpoint=ck)
        assert resumed.summary["best_epoch"] == full.summary["best_epoch"], kill_at
        assert resumed.summary["val_nll"] == full.summary["val_nll"], kill_at
        assert_same_weights(full, resumed)


def test_stop_ends_training_with_the_best_epoch_so_far():
    data, _ = synthetic(n_jobs=12, per_job=15, seed=5)
    config = TrainConfig(**EARLY)
    full = train_guide(SITES, LAYOUTS, data, config)
    asked = []

    def stop() -> bool:
        asked.append(1)
        return len(asked) >= 2

    cut = train_guide(SITES, LAYOUTS, data, config, stop=stop)
    s = cut.summary
    assert (s["epochs_run"], s["stopped"]) == (2, "stop")
    assert full.summary["epochs_run"] > 2 and full.summary["stopped"] == ""
    assert s["history"] == [
        {**h, "seconds": s["history"][k]["seconds"]}
        for k, h in enumerate(full.summary["history"][:2])
    ]
    assert s["val_nll"] == min(h["val_nll"] for h in s["history"])
