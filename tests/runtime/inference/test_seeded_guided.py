"""Seeded guided runs repeat, bit for bit, the draws, weights and evidence recorded before the
guided round was packed into kernels (commit 0095916: per-site lists, `propose_round`,
pending weights applied once per step). A change to the round loop, the features or the
guide kernel that alters any value, weight or feature row fails here.

The record holds a SHA-256 digest per run (every particle's (site, value) trace, log
weights, log prior, log evidence and step count, floats in hex), not the values. After an
intended change to the draws, rewrite it with
`UPDATE_GOLDEN=1 python -m pytest tests/runtime/inference/test_seeded_guided.py` and say
why in CHANGELOG.md. The features' sin and cos come from the C library, whose last bit may
differ between platforms: the record is checked on the architecture it was made on
(x86_64) only.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
from pathlib import Path

import pytest
from ngpm_runtime.bundled import bundled_program, default_guide, demo_targets
from ngpm_runtime.inference.likelihood import ShapeLikelihood
from ngpm_runtime.inference.smc import SMCOptions, TraceRecording, smc

RECORD = Path(__file__).parent / "data" / "seeded_guided.json"
SEEDS = (0, 1, 2)


def _digest(program, guide, target, seed: int, trace: TraceRecording) -> str:
    """SHA-256 of one guided N=10 run into `target` (the demo's settings)."""
    vp = program.viewport
    res = smc(
        program,
        ShapeLikelihood(target.mask, vp),
        10,
        guide,
        options=SMCOptions(
            seed=seed,
            ess_from_proposal=True,
            start=target.start_pose(vp),
            canvas_size=target.mask.shape,
            target_mask=target.mask,
            trace=trace,
        ),
    )
    run = {
        "traces": [
            [(s, None if f is None else f.tobytes().hex(), float(v).hex()) for s, f, v in p.trace]
            for p in res.particles
        ],
        "log_weights": [float(w).hex() for w in res.log_weights],
        "log_prior": [float(p.log_prior).hex() for p in res.particles],
        "log_evidence": float(res.log_evidence).hex(),
        "steps": res.steps,
    }
    return hashlib.sha256(json.dumps(run).encode()).hexdigest()


def _runs() -> dict[str, str]:
    program = bundled_program()
    guide = default_guide(program)
    out = {}
    for target in demo_targets()[:2]:
        for seed in SEEDS:
            out[f"{target.name}/{seed}/values"] = _digest(
                program, guide, target, seed, TraceRecording.VALUES
            )
        # full traces: the feature rows of every site visit too
        out[f"{target.name}/0/full"] = _digest(program, guide, target, 0, TraceRecording.FULL)
    return out


@pytest.mark.skipif(platform.machine() != "x86_64", reason="recorded on x86_64")
def test_seeded_guided_runs_repeat_the_record() -> None:
    got = _runs()
    if os.environ.get("UPDATE_GOLDEN"):
        RECORD.write_text(json.dumps(got, indent=1, sort_keys=True) + "\n")
        pytest.skip("record rewritten")
    want = json.loads(RECORD.read_text())
    changed = sorted(k for k in want if got.get(k) != want[k])
    assert got.keys() == want.keys() and not changed, f"runs that changed: {changed}"


def test_round_kernel_equals_the_separate_calls(monkeypatch) -> None:
    """kernels.serve_round (a round whose every site the guide's kernel serves) gives what
    the round's separate calls give (unpack, features, propose_rows, weights), bit for bit,
    full traces included; and guided runs of the bundled guide take it."""
    from ngpm_runtime import kernels
    from ngpm_runtime.inference.guide import Guide

    program = bundled_program()
    guide = default_guide(program)
    target = demo_targets()[0]
    calls = []
    serve = kernels.serve_round
    monkeypatch.setattr(kernels, "serve_round", lambda *a: calls.append(1) or serve(*a))
    modes = (TraceRecording.VALUES, TraceRecording.FULL)
    fused = [_digest(program, guide, target, 0, t) for t in modes]
    assert calls
    monkeypatch.setattr(Guide, "round_tables", lambda self, sites: None)
    calls.clear()
    assert [_digest(program, guide, target, 0, t) for t in modes] == fused
    assert not calls
