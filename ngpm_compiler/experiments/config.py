"""Settings of one evaluation run (`ngpmc eval`): one config per study (shape matching,
circuits, chain) over a shared base (`StudyConfig`), gathered with the stages to run in
`EvalConfig`; `eval_config` makes the full preset, `quick_config` the `--quick` one."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import Any

from ngpm_runtime.bundled import sampler_path

SHAPE_MODELS = ("const", "local", "local+target", "all")
STAGES = ("shape", "grids", "circuit", "chain", "report")


@dataclass
class StudyConfig:
    """What every study shares: where it writes, the grammar, training, workers and seed."""

    out: str  # results directory (CSV, PNG, report.md, README.md)
    work: str  # scratch directory (datasets, traces, models)
    quick: bool = False
    grammar: str = field(default_factory=lambda: str(sampler_path()))  # the bundled vines
    epochs: int = 40
    workers: int = 2
    backend: str = "local"  # the shape runs and chain traces: "local" processes or "ray"
    ray_address: str | None = None  # a Ray cluster (None: a local Ray instance)
    seed: int = 0


@dataclass
class ShapeConfig(StudyConfig):
    """The shape-matching study (stages shape and grids)."""

    traces: str | None = None  # canonical shape traces (None: make tiny ones in work/)
    guide_all: str | None = None  # reuse this .onnx as the all-features K=4 model
    glyphs: str | None = None  # glyph dataset dir (None: build into work/)
    silhouettes: str | None = None
    n_glyphs: int = 12
    n_silhouettes: int = 6
    ns: tuple[int, ...] = (1, 2, 5, 10, 20, 50, 100, 200)
    unguided_extra_ns: tuple[int, ...] = (600,)  # unguided only (reference, time curve)
    ablation_max_n: int = 100  # const / local / local+target: N up to this
    k1_ns: tuple[int, ...] = (1, 2, 5, 10, 20, 50, 100)
    trainset_sizes: tuple[int, ...] = (10, 30, 100, 300, 1000)
    trainset_n: int = 10  # particles for the training-set-size curve
    repeats: int = 3
    thresholds: tuple[float, ...] = tuple(round(0.05 * i, 2) for i in range(2, 19))
    grid_targets: int = 6  # targets in the result grids (half glyphs, half silhouettes)
    reference_n: int = 600
    guided_n: int = 10
    # tiny traces (quick mode, or when no canonical traces are given)
    tiny_scribbles: int = 4
    tiny_traces: int = 8
    tiny_particles: int = 40


@dataclass
class CircuitConfig(StudyConfig):
    """The circuit study (stage circuit)."""

    circuit_traces: int = 200
    circuit_particles: int = 300
    circuit_reference_n: int = 600
    circuit_guided_n: int = 15
    circuit_repeats: int = 5


@dataclass
class ChainConfig(StudyConfig):
    """The chain study of Figure 1 (stage chain)."""

    chain_grammar: str = "grammars/chain.lsys"  # relative to the current folder
    chain_train_targets: int = 40
    chain_test_targets: int = 3
    chain_traces: int = 150
    chain_particles: int = 100
    chain_ns: tuple[int, ...] = (1, 5, 20)
    chain_repeats: int = 5


@dataclass
class EvalConfig:
    """One `ngpmc eval` run: each study's settings and the stages to run."""

    shape: ShapeConfig
    circuit: CircuitConfig
    chain: ChainConfig
    stages: tuple[str, ...] = STAGES

    @property
    def out(self) -> str:
        return self.shape.out

    @property
    def work(self) -> str:
        return self.shape.work

    def studies(self) -> tuple[StudyConfig, ...]:
        return (self.shape, self.circuit, self.chain)

    def set(self, key: str, value: Any) -> None:
        """Set `key` in every study that has it (a shared setting: in all three)."""
        owners = [s for s in self.studies() if key in {f.name for f in fields(s)}]
        if not owners:
            raise KeyError(f"no evaluation setting {key!r}")
        for study in owners:
            setattr(study, key, value)

    def to_json(self) -> dict[str, Any]:
        """Every setting once (the shared ones are the same in each study), as settings.json
        keeps them."""
        out: dict[str, Any] = {}
        for study in self.studies():
            out.update(asdict(study))
        out["stages"] = self.stages
        return out


def eval_config(out: str, work: str, **settings: Any) -> EvalConfig:
    """The full preset, with `settings` (any study's setting, by name) changed."""
    cfg = EvalConfig(ShapeConfig(out, work), CircuitConfig(out, work), ChainConfig(out, work))
    for key, value in settings.items():
        cfg.set(key, value)
    return cfg


def quick_config(out: str, work: str, workers: int = 1) -> EvalConfig:
    """Small enough for CI: tiny N, two targets, two repeats, models from a few traces."""
    return eval_config(
        out,
        work,
        quick=True,
        n_glyphs=1,
        n_silhouettes=1,
        ns=(1, 3),
        unguided_extra_ns=(6,),
        ablation_max_n=3,
        k1_ns=(1, 3),
        trainset_sizes=(2, 4),
        trainset_n=3,
        repeats=2,
        thresholds=(0.05, 0.1, 0.2, 0.3),
        epochs=2,
        grid_targets=2,
        reference_n=6,
        guided_n=3,
        tiny_scribbles=3,
        tiny_traces=5,
        tiny_particles=20,
        circuit_traces=3,
        circuit_particles=15,
        circuit_reference_n=8,
        circuit_guided_n=3,
        circuit_repeats=2,
        chain_train_targets=4,
        chain_test_targets=1,
        chain_traces=4,
        chain_particles=10,
        chain_ns=(1, 3),
        chain_repeats=2,
        workers=workers,
    )
