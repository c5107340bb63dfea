"""The evaluation's settings: one config per study over a shared base."""

from __future__ import annotations

from dataclasses import fields

import pytest

from ngpm_compiler.experiments.config import (
    ChainConfig,
    CircuitConfig,
    ShapeConfig,
    StudyConfig,
    eval_config,
    quick_config,
)


def test_a_shared_setting_reaches_every_study_and_a_study_setting_only_its_own() -> None:
    cfg = eval_config("out", "work", workers=5, seed=7, circuit_traces=9, chain_ns=(2,))
    assert [s.workers for s in cfg.studies()] == [5, 5, 5]
    assert [s.seed for s in cfg.studies()] == [7, 7, 7]
    assert cfg.circuit.circuit_traces == 9 and cfg.chain.chain_ns == (2,)
    assert not hasattr(cfg.shape, "circuit_traces") and not hasattr(cfg.chain, "ns")
    with pytest.raises(KeyError, match="no evaluation setting 'nss'"):
        cfg.set("nss", (1,))


def test_the_studies_share_only_the_base_fields() -> None:
    base = {f.name for f in fields(StudyConfig)}
    own = [{f.name for f in fields(c)} - base for c in (ShapeConfig, CircuitConfig, ChainConfig)]
    assert all(own) and not (own[0] & own[1] or own[0] & own[2] or own[1] & own[2])


def test_settings_json_names_every_setting_once() -> None:
    cfg = quick_config("out", "work", workers=2)
    settings = cfg.to_json()
    names = {f.name for c in (ShapeConfig, CircuitConfig, ChainConfig) for f in fields(c)}
    assert set(settings) == names | {"stages"}
    assert settings["quick"] is True and settings["workers"] == 2
    assert settings["ns"] == (1, 3) and settings["circuit_traces"] == 3
    assert settings["chain_traces"] == 4 and settings["stages"] == cfg.stages
