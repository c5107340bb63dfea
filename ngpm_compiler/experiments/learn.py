"""`ngpmc learn`: the project's guide-training recipe (scripts/train_vines_guide.sh) as one
resumable, budget-aware run for any 2D or 3D grammar.

Stages, each finished one recorded in OUT/learn.json (with its wall time) and skipped when
the same command runs again: `diagnose` (evaluation/diagnose.py: refuse a grammar that
explodes or cannot get a viewport; copy the grammar into OUT, with the proposed viewport
when it has none), `targets` (training: scribbles + varied, mirrored, or --targets;
validation: varied and procedural shapes of other seeds; --targets envelopes: envelopes
of the grammar's own samples, datasets/envelopes.py), `reach` (what unguided SMC reaches on
3 training targets: a warning when it is too little for a guide to learn from),
`envelopes` (without --targets, after a low reach: training and validation switch to the
grammar's envelopes when unguided SMC reaches them better; 2D only), `measure` (two unguided trace
jobs per worker, run as the rounds run them: seconds per particle), `plan`
(learn_plan.py), `round_00` (unguided traces, training, validation; on envelope targets
every round records ground-truth traces instead, `record_own`), `replan` (guided
trace jobs timed, the guided rounds planned anew), `round_01`... (traces from SMC guided
by the best round so far, training on every round's traces, validation: expert iteration
as learning/rounds.py, rounds scored under equal, default proposal settings), `fill_<e>_<k>`
(rounds with a stronger teacher added while the measured costs leave room), `tune`
(learning/tune.py on the best round), `curve` (similarity vs N, guided and unguided, on the
validation targets), then OUT/report.md and curve.png. OUT/guide.onnx is written after
every round and after tuning.

A rerun with a larger `--budget` than the latest plan was made under extends it
(`extend_1`, `extend_2`...: learn_plan.extend): the finished rounds stay, the guided rounds
that fit the time left are added (numbered on), and tuning and the curve run again for the
new guide (`tune_1`, `curve_1`...; their cached runs are reused).

Inside a stage the library's own resumption holds: trace shards, a training checkpoint
and the validation run cache, so Ctrl-C loses only the unfinished part. The budget counts
the wall time of every run on OUT; past it the run stops at the next trace, epoch or
stage, keeps the best finished round's guide, and writes the report.

A 3D grammar (a `viewport:` box of six numbers) learns the same way into 3D target sets
(datasets/sets3d.py): training on `blobs3d` and `extruded` targets, mirrored when built,
validation on other seeds of both (never the held-out `revolved` set), features `all` (3D
rows have no context group).

Short traces are kept as data, as `ngpmc traces` and `iterate` keep them by default
(learning/trace_jobs.MIN_PRIMITIVES: 1, not the paper's 10).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from ngpm_runtime.errors import NgpmError
from ngpm_runtime.files import atomic_write

from ngpm_compiler.evaluation.diagnose import REACH_LOW, reach_line
from ngpm_compiler.experiments.learn_plan import (
    CURVE_REPEATS,
    ENVELOPE_TRAINING,
    FEATURES,
    GUIDED_PARTICLES,
    MIN_TRACES,
    OWN_TEACHER,
    TRAIN_FIXED,
    TRAIN_SECONDS,
    UNGUIDED_PARTICLES,
    Costs,
    Plan,
    extend,
    fill,
    plan,
    replan,
    reserve_seconds,
    round_seconds,
    trace_allowance,
    traces_that_fit,
    train_per_trace,
    validation_seconds,
)
from ngpm_compiler.learning.trace_jobs import MIN_PRIMITIVES
from ngpm_compiler.progress import Log

STATE_FORMAT = "ngpm-learn/1"
TRAIN_DATASETS = ("scribbles", "varied")
# name: (dataset, seed); the seeds differ from the training sets' (cfg.seed + i), so the
# validation targets are held out (targets_stage checks it)
VALIDATION = {"varied": ("varied", 9001), "shapes": ("shapes", 9101)}
# a 3D grammar's training and validation sets (held out as above)
TRAIN_DATASETS_3D = ("blobs3d", "extruded")
VALIDATION_3D = {"blobs3d": ("blobs3d", 9001), "extruded": ("extruded", 9101)}
VAL_COUNT = 12  # targets built per validation set (plans pick up to this many)
# `--targets envelopes`: the grammar's own envelopes (datasets/envelopes.py), also chosen
# when unguided SMC reaches the generic targets too poorly; validated on another seed's
ENVELOPES = "envelopes"
ENVELOPE_VALIDATION = {"envelopes": ("envelopes", 9201)}
# on envelope targets every round records ground-truth traces, not SMC's: each a forward
# sample recorded into its own envelope (TraceConfig.own_samples), OWN_TRACES more a round
# (experiments/notes/own_samples.md: lazy bush held out 0.47 -> 0.63 at N = 10 from 8000;
# SMC teachers' traces added to them lowered validation round by round)
OWN_TRACES = 8000
# particles of the measured jobs when the budget is under 2 minutes (else round 0's: a job's
# fixed cost at 100 particles made lily's 6-minute run plan for 6x its per-particle cost)
MEASURE_SMALL = 100
REPLAN_ROOM = 60.0  # seconds left after round 0 beside tuning and the curve: plan guided rounds


class LearnError(NgpmError):
    """`ngpmc learn` cannot go on (a grammar it cannot train for, a budget too small)."""


class TracesTimeUp(Exception):
    """A round's traces used their share of the budget: the round trains on what it has."""


class BudgetSpent(Exception):
    """The budget ran out; `where` names what was running."""

    def __init__(self, where: str) -> None:
        super().__init__(where)
        self.where = where


@dataclass
class LearnConfig:
    grammar: str  # .lsys file
    out: str
    budget: float = 45 * 60.0  # seconds
    likelihood: str = "shape"
    targets: list[str] = field(default_factory=list)  # training directories ([]: build)
    validation: dict[str, str] = field(default_factory=dict)  # name -> dir ({}: build)
    workers: int = 2
    seed: int = 0
    progress: bool = True
    tune_teachers: bool = False  # tune a guided round's teacher first (tuned_teacher)


class Clock:
    """The budget: seconds spent on OUT before this run plus this run's."""

    def __init__(self, budget: float, before: float) -> None:
        self.budget, self.before, self.t0 = budget, before, time.perf_counter()

    def spent(self) -> float:
        return self.before + time.perf_counter() - self.t0

    def left(self) -> float:
        return self.budget - self.spent()

    def check(self, where: str) -> None:
        if self.left() <= 0:
            raise BudgetSpent(where)


@dataclass
class Run:
    """One `learn` call: its configuration, state (learn.json), clock and log."""

    cfg: LearnConfig
    state: dict[str, Any]
    clock: Clock
    log: Log

    @property
    def out(self) -> Path:
        return Path(self.cfg.out)

    def save(self) -> None:
        self.state["spent"] = round(self.clock.spent(), 3)
        atomic_write(self.out / "learn.json", json.dumps(self.state, indent=1) + "\n")

    def stage(self, name: str, fn: Any) -> Any:
        """fn()'s result, or the recorded one when the stage finished before."""
        done = self.state["stages"].get(name)
        if done is not None:
            return done["result"]
        self.log(f"{name}: started ({_minutes(self.clock.left())} of the budget left)")
        t0 = time.perf_counter()
        result = fn()
        seconds = round(time.perf_counter() - t0, 3)
        self.state["stages"][name] = {"seconds": seconds, "result": result}
        self.save()
        self.log(f"{name}: done in {_minutes(seconds)}")
        return result


def _minutes(seconds: float) -> str:
    if seconds < 120:
        return f"{max(seconds, 0):.0f} s"
    return f"{seconds / 60:.1f} min"


def _key(cfg: LearnConfig) -> dict[str, Any]:
    import hashlib

    text = Path(cfg.grammar).read_bytes()
    return {
        "grammar": Path(cfg.grammar).name,
        "grammar_sha": hashlib.sha256(text).hexdigest(),
        "likelihood": cfg.likelihood,
        "seed": cfg.seed,
        "targets": [t if t == ENVELOPES else str(Path(t).resolve()) for t in cfg.targets],
        "validation": {k: str(Path(v).resolve()) for k, v in sorted(cfg.validation.items())},
        **({"tune_teachers": True} if cfg.tune_teachers else {}),  # runs before it resume
    }


def open_run(cfg: LearnConfig, log: Log) -> Run:
    """The run on cfg.out: a new one, or the one there (refused if of another config)."""
    out = Path(cfg.out)
    if out.exists() and not out.is_dir():
        raise LearnError(f"{out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    key = _key(cfg)
    path = out / "learn.json"
    state: dict[str, Any] = {"format": STATE_FORMAT, "key": key, "spent": 0.0, "stages": {}}
    if path.is_file():
        try:
            old = json.loads(path.read_text(encoding="utf-8"))
        except ValueError:
            raise LearnError(f"{path}: not valid JSON; remove it or use another -o") from None
        if old.get("format") != STATE_FORMAT or old.get("key") != key:
            was = old.get("key", {})
            diff = sorted(k for k in key.keys() | was.keys() if was.get(k) != key.get(k))
            raise LearnError(
                f"{out}: holds a learn run of another configuration (differs in "
                f"{', '.join(diff) or 'format'}); use another -o"
            )
        state = old
        log(f"resuming {out}: {len(state['stages'])} stages done, {_minutes(state['spent'])} spent")
    run = Run(cfg, state, Clock(cfg.budget, float(state.get("spent", 0.0))), log)
    run.save()
    return run


# --------------------------------------------------------------------------- stages


def diagnose_stage(run: Run) -> dict[str, Any]:
    """Check the grammar (one-line errors) and copy it into OUT, with the proposed viewport
    when it has none; the estimates' lines for the report."""
    from ngpm_compiler.evaluation.diagnose import (
        diagnose,
        hint_lines,
        sample_lines,
        viewport_line,
    )
    from ngpm_compiler.language.compile import compile_grammar

    cfg = run.cfg
    compiled = compile_grammar(Path(cfg.grammar), filename=cfg.grammar)
    program = compiled.program()
    if program.dim == 3:
        _check_3d(cfg, program)
    quick = min(1.0, cfg.budget / 600)  # a tiny budget gets a quicker look (diagnose keeps
    # its forward samples' time cap at 8 s at least: a quick look refuses no grammar that ends)
    diag = diagnose(compiled, samples=40, seed=cfg.seed, budget=2 * quick, time_smc=3 * quick)
    _refuse_exploding(cfg.grammar, diag)
    text = compiled.source_text
    proposed = None
    if program.viewport is None:
        if diag.viewport is None:
            raise LearnError(
                f"{cfg.grammar}: no 'viewport:' line, and its samples draw nothing to "
                "propose one from; add one (e.g. 'viewport: -12 12 -22 2')"
            )
        proposed = list(diag.viewport)
        text = f"{viewport_line(diag.viewport)}  # proposed by ngpmc learn\n{text}"
    grammar = run.out / Path(cfg.grammar).name
    atomic_write(grammar, text.encode("utf-8"))
    return {
        "grammar": str(grammar),
        "viewport_proposed": proposed,
        "smc_seconds": diag.timing.seconds if diag.timing else None,
        "lines": sample_lines(diag) + hint_lines(diag, compiled.checked),
        "dim": program.dim,
    }


def _check_3d(cfg: LearnConfig, program: Any) -> None:
    """LearnError for what a 3D grammar cannot learn with: another likelihood than the
    shape (voxels), envelopes, or no box to place 3D targets in."""
    if cfg.likelihood != "shape":
        raise LearnError(
            f"{cfg.grammar}: a 3D grammar learns with the shape likelihood (voxels); "
            f"--likelihood {cfg.likelihood} is for 2D grammars"
        )
    if cfg.targets == [ENVELOPES]:
        raise LearnError(
            f"{cfg.grammar}: --targets envelopes is for 2D grammars; give 3D target sets "
            "(ngpmc targets build blobs3d ...) or none"
        )
    if program.box is None:
        raise LearnError(
            f"{cfg.grammar}: a 3D grammar needs its box to grow into targets: add a "
            "'viewport: XMIN XMAX YMIN YMAX ZMIN ZMAX' line"
        )


def dim_of(run: Run) -> int:
    """2 or 3: the grammar's dimension as the `diagnose` stage found it (2 before it, and in
    a learn.json older than 3D learning)."""
    done = run.state.get("stages", {}).get("diagnose")
    return int(done["result"].get("dim", 2)) if done else 2


def _refuse_exploding(filename: str, diag: Any) -> None:
    """LearnError when forward samples run to a cap: a supercritical rule (named), or a
    grammar that does not end by itself."""
    from ngpm_compiler.evaluation.diagnose import warning_lines

    s = diag.samples
    if s is None or not s.capped:
        return
    if diag.branching:
        b = diag.branching[0]
        raise LearnError(
            f"{filename}:{b.line}: rule {b.pred} branches supercritically ({b.rate:.2f} "
            f"per generation) and {s.capped} of {s.n} samples ran to a cap: every SMC run "
            "would draw to the cap; make it fork less often or end its chains (ngpmc check)"
        )
    if s.capped * 2 > s.n:
        first = warning_lines(diag)[0].removeprefix("warning: ")
        raise LearnError(first)


def targets_stage(run: Run, grammar: str | None = None) -> dict[str, Any]:
    """Training and validation target directories (built under OUT/targets; envelopes of
    `grammar`, OUT's copy (default the config's), with --targets envelopes)."""
    from ngpm_compiler.datasets.build import build_dataset

    cfg, root = run.cfg, run.out / "targets"
    if cfg.likelihood == "circuit":  # no targets: blank canvases (grow.circuit_target)
        from ngpm_compiler.evaluation.heldout import CIRCUIT_SETS

        return {"train": [""], "validation": dict(CIRCUIT_SETS)}
    if cfg.targets == [ENVELOPES]:
        return envelope_targets(run, grammar or cfg.grammar)
    three = dim_of(run) == 3
    datasets = TRAIN_DATASETS_3D if three else TRAIN_DATASETS
    val_sets = VALIDATION_3D if three else VALIDATION
    train = list(cfg.targets)
    seen = {(name, cfg.seed + i) for i, name in enumerate(datasets)}
    if not cfg.targets and seen & set(val_sets.values()) and not cfg.validation:
        raise LearnError(
            f"--seed {cfg.seed} would build training targets equal to the validation targets; "
            "choose another seed"
        )
    if not train:
        count = _train_count(cfg.budget)
        for i, name in enumerate(datasets):
            build_dataset(name, root / name, count=count, seed=cfg.seed + i, mirror=True)
            train.append(str(root / name))
    validation = dict(cfg.validation)
    if not validation:
        for name, (dataset, seed) in val_sets.items():
            build_dataset(dataset, root / f"val_{name}", count=VAL_COUNT, seed=seed)
            validation[name] = str(root / f"val_{name}")
    return {"train": train, "validation": validation, "kind": "given" if cfg.targets else "generic"}


def _train_count(budget: float) -> int:
    """Training targets built per set: 300 from a 30-minute budget, fewer below."""
    return 300 if budget >= 1800 else max(8, min(300, int(budget / 6)))


def envelope_targets(run: Run, grammar: str) -> dict[str, Any]:
    """Envelopes of the grammar's forward samples (datasets/envelopes.py) under OUT/targets:
    training (seed --seed, mirrored) and validation (ENVELOPE_VALIDATION's seed)."""
    from ngpm_compiler.datasets.build import build_dataset

    cfg, root = run.cfg, run.out / "targets"
    if cfg.seed in {seed for _, seed in ENVELOPE_VALIDATION.values()}:
        raise LearnError(
            f"--seed {cfg.seed} would build training envelopes equal to the validation "
            "envelopes; choose another seed"
        )
    count = _train_count(cfg.budget)
    build_dataset(
        ENVELOPES, root / ENVELOPES, count=count, seed=cfg.seed, mirror=True, grammar=grammar
    )
    validation = {}
    for name, (dataset, seed) in ENVELOPE_VALIDATION.items():
        build_dataset(dataset, root / f"val_{name}", count=VAL_COUNT, seed=seed, grammar=grammar)
        validation[name] = str(root / f"val_{name}")
    return {"train": [str(root / ENVELOPES)], "validation": validation, "kind": ENVELOPES}


def targets_of(run: Run) -> dict[str, Any]:
    """The targets the run trains and validates on: the `targets` stage's, or the
    envelopes the `envelopes` stage switched to."""
    stages = run.state["stages"]
    switch = stages.get("envelopes")
    if switch is not None and switch["result"]["switched"]:
        return dict(switch["result"]["targets"])
    return dict(stages["targets"]["result"])


REACH_SHARE = 0.02  # of the budget the reachability runs may take


def reach_stage(run: Run, d: dict[str, Any], train: str) -> dict[str, Any]:
    """The reachability of the first training directory, with the warning line."""
    r = reach_of(run, d, train)
    return {
        **asdict(r),
        "low": r.low,
        "warning": reach_line(r, Path(run.cfg.grammar).name) if r.low else None,
    }


def reach_of(run: Run, d: dict[str, Any], train: str) -> Any:
    """What unguided SMC reaches on a few training targets (evaluation/diagnose.py
    reachability), with REACH_N particles or as many as fit REACH_SHARE of the budget (the
    stage's warning says what to change when it is low; learn goes on)."""
    from ngpm_compiler.evaluation.diagnose import (
        REACH_N,
        REACH_N_3D,
        REACH_TARGETS,
        TARGET_N,
        reachability,
    )
    from ngpm_compiler.evaluation.heldout import load_sets
    from ngpm_compiler.language.compile import load_grammar

    program = load_grammar(d["grammar"])
    per_run = (d["smc_seconds"] or 1.0) / TARGET_N  # seconds per particle
    fit = int(REACH_SHARE * run.cfg.budget / (REACH_TARGETS * per_run))
    n = max(10, min(REACH_N_3D if program.dim == 3 else REACH_N, fit))
    targets = load_sets({"train": train}, REACH_TARGETS, program)["train"]
    return reachability(program, targets, n, seed=run.cfg.seed)


def envelopes_stage(run: Run, d: dict[str, Any], generic: dict[str, Any]) -> dict[str, Any]:
    """After a low `reach` on the generic targets: build the grammar's envelopes, measure
    what unguided SMC reaches on them, and switch training and validation to them when it
    reaches more; the one-line reason (with both similarities) for the log and the report."""
    from ngpm_compiler.datasets.common import DatasetError

    name = Path(run.cfg.grammar).name
    try:
        targets = envelope_targets(run, d["grammar"])
    except DatasetError as err:
        line = f"{generic['warning']} (no envelopes of its own samples either: {err})"
        return {"switched": False, "targets": None, "reach": None, "line": line}
    r = reach_of(run, d, targets["train"][0])
    switched = r.similarity > generic["similarity"]
    seen = (
        f"unguided SMC with {generic['n']} particles reaches similarity "
        f"{generic['similarity']:.3f} on the generic training targets (below {REACH_LOW}) "
        f"and {r.similarity:.3f} on envelopes of {name}'s own samples"
    )
    if switched:
        line = (
            f"targets: {seen}: training and validating on envelopes instead "
            f"({run.out / 'targets'}; --targets DIR chooses others)"
        )
    else:
        line = (
            f"{generic['warning']} (envelopes of its own samples reach {r.similarity:.3f}, "
            "no better: keeping the generic targets)"
        )
    return {"switched": switched, "targets": targets, "reach": asdict(r), "line": line}


def measure_stage(
    run: Run, grammar: str, train: str, particles: int, guide: str | None = None
) -> float:
    """Seconds per particle of trace jobs (unguided, or guided by `guide`): two jobs per
    worker on the first training directory, run as the rounds run them (the workers side
    by side), in OUT/measure/."""
    from ngpm_compiler.learning.traces import TraceConfig, generate_traces

    tc = TraceConfig(
        grammar=grammar,
        targets=train,
        n=2 * run.cfg.workers,
        particles=particles,
        seed=run.cfg.seed + 7,
        workers=run.cfg.workers,
        min_primitives=MIN_PRIMITIVES,
        guide=guide,
        **_trace_options(run.cfg.likelihood, dim_of(run)),
    )
    out = run.out / "measure" / ("guided" if guide else "unguided")
    m = generate_traces(tc, out, progress=False, on_job=lambda _j: run.clock.check("measuring"))
    secs = m["job_seconds"]
    return float(sum(secs) / max(1, len(secs)) / particles)


def _costs(run: Run) -> Costs:
    c = run.state.get("costs", {})
    sets = len(targets_of(run)["validation"])
    return Costs(
        unguided=float(c["unguided"]),
        guided=float(c.get("guided", 0.0)),
        val_run=float(c.get("val_run", 0.0)),
        train=float(c.get("train", TRAIN_SECONDS)),
        workers=run.cfg.workers,
        sets=sets,
    )


def plan_stage(run: Run) -> dict[str, Any]:
    p = replace(plan(max(1.0, run.clock.left()), _costs(run)), total=run.cfg.budget)
    for line in p.reasons:
        run.log(f"plan: {line}")
    return asdict(p)


def measure_guided(run: Run, p: Plan) -> None:
    """Guided trace jobs timed (round 0's guide teaching), and round 0's validation and
    training times, into the run's costs."""
    r0 = run.state["stages"]["round_00"]["result"]
    d = run.state["stages"]["diagnose"]["result"]
    train = targets_of(run)["train"]
    costs = run.state["costs"]
    costs["guided"] = measure_stage(run, d["grammar"], train[0], GUIDED_PARTICLES, r0["guide"])
    c = _costs(run)
    runs = c.sets * p.val_targets * p.val_repeats  # guided runs (and as many unguided)
    costs["val_run"] = r0["seconds"]["validation"] * max(1, c.workers) / max(1, runs)
    costs["train"] = train_cost([r0])


def replan_stage(run: Run, p: Plan) -> dict[str, Any]:
    """After round 0: measure guided trace jobs and a guided validation run, then plan the
    guided rounds anew."""
    measure_guided(run, p)
    r0 = run.state["stages"]["round_00"]["result"]
    q = replan(p, max(0.0, run.clock.left()), _costs(run), r0["traces"])
    q = replace(q, total=run.cfg.budget)
    run.log(f"plan: {q.reasons[-1]}")
    if targets_of(run).get("kind") == ENVELOPES:
        run.log(
            f"plan: on envelopes each round records {OWN_TRACES} ground-truth traces "
            "(its own samples) in place of the guided traces planned"
        )
    return asdict(q)


def planned_under(run: Run, p: Plan) -> float:
    """The --budget plan `p` was made under (a plan of an older learn.json does not say:
    its seconds plus those of the stages before it)."""
    if p.total:
        return p.total
    stages = run.state["stages"]
    return p.budget + sum(stages[k]["seconds"] for k in ("diagnose", "targets", "measure"))


def extensions(run: Run) -> list[str]:
    """The finished extend_<k> stages, in order."""
    names = [k for k in run.state["stages"] if k.startswith("extend_")]
    return sorted(names, key=lambda k: int(k.removeprefix("extend_")))


def extended(run: Run, p: Plan) -> Plan:
    """The latest plan (`p` or the last extension's); a new extension when this run's
    --budget is larger than the one that plan was made under."""
    names = extensions(run)
    if names:
        p = load_plan(run.state["stages"][names[-1]]["result"]["plan"])
    before = planned_under(run, p)
    if run.cfg.budget <= before + 1.0:
        return p
    run.clock.check("planning more rounds")
    run.log(
        f"the budget grew from {_minutes(before)} to {_minutes(run.cfg.budget)}: "
        f"planning more rounds for the {_minutes(run.clock.left())} left"
    )
    name = f"extend_{len(names) + 1}"
    res = run.stage(name, lambda: extend_stage(run, p, before))
    return load_plan(res["plan"])


def extend_stage(run: Run, p: Plan, before: float) -> dict[str, Any]:
    """The plan `p` extended by the guided rounds that fit what is left of the larger
    budget (learn_plan.extend), from the costs the rounds measured."""
    rows = _rounds(run)
    if "guided" not in run.state["costs"]:  # round 0 alone was planned: time guided SMC
        measure_guided(run, p)
    costs, val = _round_costs(run, p)
    done = rows[-1]["round"]
    cut = (run.out / "rounds" / f"round_{done + 1}").exists()  # a round the budget cut
    curve_done = any(k.startswith("curve") for k in run.state["stages"])
    q = extend(
        p,
        run.cfg.budget,
        max(0.0, run.clock.left()),
        costs,
        done,
        rows[-1]["traces"],
        val,
        fixed=cut,
        curve_done=curve_done,
    )
    run.log(f"plan: {q.reasons[-1]}")
    tuned = any(k.startswith("tune") and v["result"] for k, v in run.state["stages"].items())
    return {
        "plan": asdict(q),
        "after_round": done,
        "budget_before": before,
        "spent": round(run.clock.spent(), 3),
        # new rounds, or a tune grid where none was tuned: tuning and the curve run again
        "renews": q.rounds > done or bool(q.choice_temperatures and not tuned),
    }


def final_suffix(run: Run) -> str:
    """'' or '_<k>': the stage names of the tuning and curve that belong to the latest
    extension that renews them (tune_<k>, curve_<k>; tune and curve without one)."""
    from ngpm_compiler.experiments.learn_report import renewing

    ks = renewing(run.state["stages"])
    return f"_{ks[-1]}" if ks else ""


def load_plan(d: dict[str, Any]) -> Plan:
    tuples = ("choice_temperatures", "ess", "curve_guided", "curve_unguided", "reasons")
    fields: dict[str, Any] = {k: tuple(v) if k in tuples else v for k, v in d.items()}
    fields["more"] = tuple((int(n), int(pg)) for n, pg in d.get("more", ()))
    return Plan(**fields)


# --------------------------------------------------------------------------- rounds


def _rounds_config(run: Run, p: Plan, r: int) -> Any:
    """Round r's settings (its traces and teacher particles: Plan.round_settings)."""
    from ngpm_compiler.learning.rounds import RoundsConfig

    t = targets_of(run)
    n, particles = p.round_settings(r) if r > 0 else (p.traces, p.guided_particles)
    own = t.get("kind") == ENVELOPES
    training: dict[str, Any] = (
        dict(ENVELOPE_TRAINING) if own else {"feature_set": FEATURES[dim_of(run)]}
    )
    return RoundsConfig(
        grammar=run.state["stages"]["diagnose"]["result"]["grammar"],
        targets=t["train"],
        validation=t["validation"],
        out=str(run.out / "rounds"),
        rounds=p.last_round,
        n=n,
        particles=particles,
        unguided_particles=p.unguided_particles,
        val_targets=p.val_targets,
        val_repeats=p.val_repeats,
        **training,
        workers=run.cfg.workers,
        seed=run.cfg.seed,
        likelihood=run.cfg.likelihood,
    )


def _trace_options(likelihood: str, dim: int) -> dict[str, Any]:
    """TraceConfig's likelihood and mirroring: 2D shape targets get mirrored copies, the
    circuit likelihood has no targets to mirror, and 3D sets are mirrored when built."""
    return {"likelihood": likelihood, "mirror": likelihood == "shape" and dim == 2}


def record(run: Run, rc: Any, r: int, teacher: str | None, allow: float) -> tuple[list[str], float]:
    """Round r's traces (one directory per training directory), each directory stopped
    at its share of `allow` seconds; (dirs, seconds per particle of their jobs)."""
    from ngpm_compiler.learning.traces import TraceConfig

    dirs, per = [], []
    t0 = time.perf_counter()
    for i, targets in enumerate(rc.targets):
        out = Path(rc.out) / f"round_{r}" / f"traces_{i}"
        tc = TraceConfig(
            grammar=rc.grammar,
            targets=targets,
            n=math.ceil(rc.n / len(rc.targets)),
            particles=rc.particles if teacher else rc.unguided_particles,
            seed=rc.seed + 1000 * r + i,
            workers=rc.workers,
            min_primitives=MIN_PRIMITIVES,
            guide=teacher,
            **_trace_options(rc.likelihood, dim_of(run)),
        )
        m = _traces_until(run, r, tc, out, t0 + allow * (i + 1) / len(rc.targets))
        secs = m["job_seconds"]
        if secs:
            per.append(sum(secs) / len(secs) / tc.particles)
        run.log(
            f"round {r}: {out}: {m['kept']} traces ({m['dropped']} dropped), "
            f"{m['seconds']:.0f} s, {'guided by ' + teacher if teacher else 'unguided'}"
        )
        dirs.append(str(out))
    return dirs, sum(per) / max(1, len(per))


def _traces_until(run: Run, r: int, tc: Any, out: Path, until: float) -> dict[str, Any]:
    """Round r's traces of `tc` into `out`, stopped (and noted) at `until` (perf_counter
    seconds) or by the budget; their manifest."""
    from ngpm_compiler.learning.traces import generate_traces

    def on_job(_job: int) -> None:
        run.clock.check(f"round {r}'s traces")
        if time.perf_counter() > until:
            raise TracesTimeUp

    try:
        return generate_traces(tc, out, progress=run.cfg.progress, on_job=on_job)
    except TracesTimeUp:
        m: dict[str, Any] = json.loads((out / "manifest.json").read_text(encoding="utf-8"))
        run.log(f"round {r}: {out}: traces stopped at their share of the budget")
        run.state.setdefault("notes", []).append(
            f"round {r}: {out.name} stopped at its share of the budget: "
            f"{m['kept']} of {tc.n} traces"
        )
        return m


def record_own(run: Run, rc: Any, r: int, allow: float) -> tuple[list[str], float]:
    """Round r's traces on envelope targets: OWN_TRACES ground-truth traces (forward
    samples, each recorded into its own envelope: TraceConfig.own_samples; each round its
    own seed), stopped at `allow` seconds; ([dir], seconds per particle of the round's
    planned SMC traces that cost as much: rc.n traces of the round's particles, so the
    plan's estimates of later rounds hold)."""
    from ngpm_compiler.learning.traces import TraceConfig

    out = Path(rc.out) / f"round_{r}" / "own_samples"
    tc = TraceConfig(
        grammar=rc.grammar,
        targets="",
        n=OWN_TRACES,
        particles=1,
        seed=rc.seed + 1000 * r,
        workers=rc.workers,
        own_samples=True,
    )
    m = _traces_until(run, r, tc, out, time.perf_counter() + allow)
    run.log(f"round {r}: {out}: {m['kept']} traces, {m['seconds']:.0f} s, {OWN_TEACHER}")
    particles = rc.particles if r > 0 else rc.unguided_particles
    return [str(out)], sum(m["job_seconds"]) / max(1, rc.n * particles)


def train(
    run: Run, rc: Any, r: int, trace_dirs: list[str], keep: float = 0.0
) -> tuple[str, dict[str, Any]]:
    """Train round r's guide on every round's traces (checkpointed, stopped by the budget
    between epochs, and early once fewer than `keep` seconds of it are left: the round's
    validation, tuning and the curve) and export it; (onnx path, training summary)."""
    from ngpm_compiler.learning.export import write_onnx
    from ngpm_compiler.learning.rounds import merge_traces, train_config, warm_init
    from ngpm_compiler.learning.trace_data import load_traces
    from ngpm_compiler.learning.train import save_model, train_guide

    ts = merge_traces([load_traces(d) for d in trace_dirs])
    if not ts.data:
        raise LearnError(f"round {r}: the traces hold no site visits to train on")
    folder = Path(rc.out) / f"round_{r}"
    where = f"round {r}'s training"
    init = warm_init(rc, r)
    model = train_guide(
        ts.sites,
        ts.layouts,
        ts.data,
        train_config(rc, warm=init is not None),
        grammar=ts.manifest["key"]["grammar"],
        grammar_hash=ts.manifest["grammar_hash"],
        checkpoint=folder / "model.pt.ckpt",
        progress=run.cfg.progress,
        on_epoch=lambda _row: run.clock.check(where),
        stop=lambda: run.clock.left() < keep,
        init=init,
    )
    save_model(model, folder / "model.pt")
    (folder / "model.pt.ckpt").unlink(missing_ok=True)
    s = model.summary
    cut = f", stopped after {s['epochs_run']} epochs to keep {keep:.0f} s" if s["stopped"] else ""
    run.log(
        f"round {r}: trained on {s['traces']} traces, validation NLL {s['val_nll']:.2f}, "
        f"{s['seconds']:.0f} s{cut}"
    )
    return str(write_onnx(model, folder / "guide.onnx")), s


def round_stage(run: Run, p: Plan, r: int) -> dict[str, Any]:
    """Round r: traces (round 0 unguided, then guided by the best round so far; on envelope
    targets ground-truth traces every round, `record_own`), training on every round's
    traces, validation at N = 10 under default proposal settings."""
    from ngpm_compiler.learning.rounds import validate

    rc = _rounds_config(run, p, r)
    rows = _rounds(run)
    best = max(rows, key=lambda x: x["validation"]) if rows else None
    teacher = best["guide"] if best else None
    t0 = time.perf_counter()
    setting = ""
    own = targets_of(run).get("kind") == ENVELOPES
    if best is not None and run.cfg.tune_teachers and not own:
        teacher, setting = tuned_teacher(run, p, best)
    costs, keep = _round_needs(run, p, rc, rows)
    allow = _allowance(run, rc, rows, teacher, costs, keep)
    if own:
        dirs, per_particle = record_own(run, rc, r, allow)
    else:
        dirs, per_particle = record(run, rc, r, teacher, allow)
    trace_dirs = [d for x in rows for d in x["traces_dirs"]] + dirs
    t1 = time.perf_counter()
    path, summary = train(run, rc, r, trace_dirs, keep)
    t2 = time.perf_counter()
    run.clock.check(f"round {r}'s validation")
    score = validate(rc, f"round_{r}", path, run.log)
    return {
        "round": r,
        "teacher": OWN_TEACHER
        if own
        else f"guided N={rc.particles} by round {best['round']}{setting}"
        if best
        else f"unguided N={rc.unguided_particles}",
        "traces": summary["traces"],
        "features": rc.feature_set,
        "patience": summary["config"]["patience"],
        "hidden_per_input": rc.hidden_per_input,
        "warm_start": bool(summary.get("warm_started")),
        "val_nll": round(float(summary["val_nll"]), 3),
        "validation": round(score, 4),
        "guide": path,
        "traces_dirs": dirs,
        "seconds_per_particle": per_particle,
        "train_seconds_per_trace": (t2 - t1) / max(1, summary["traces"]),
        "train_epochs": summary["epochs_run"],
        "train_stopped": bool(summary["stopped"]),
        "seconds": {"traces": t1 - t0, "train": t2 - t1, "validation": time.perf_counter() - t2},
    }


def _round_needs(run: Run, p: Plan, rc: Any, rows: list[dict[str, Any]]) -> tuple[Costs, float]:
    """The costs the rounds so far measured (as the round's own estimate and the fill plan
    were made), and the seconds a round must leave after its training: its validation, then
    tuning and the curve (a training longer than its estimate stops early rather than
    squeeze out tuning)."""
    costs, val = _round_costs(run, p) if rows else (_costs(run), 0.0)
    val = val or validation_seconds(costs, rc.val_targets, rc.val_repeats)
    return costs, val + _reserve(run, p)


def _allowance(
    run: Run, rc: Any, rows: list[dict[str, Any]], teacher: str | None, costs: Costs, keep: float
) -> float:
    """Seconds this round's traces may take (learn_plan.trace_allowance) at `costs`, before
    its training and the `keep` seconds after it."""
    particles = rc.particles if teacher else rc.unguided_particles
    planned = rc.n * costs.trace(particles, teacher is not None) / max(1, costs.workers)
    trained = (rows[-1]["traces"] if rows else 0) + rc.n
    after = TRAIN_FIXED + costs.train * trained
    return trace_allowance(planned, run.clock.left(), after + keep)


def train_cost(rows: list[dict[str, Any]]) -> float:
    """Training seconds per trace as the last round measured them; when its training was
    stopped early for time, at least what the rounds before it measured (a cut training
    does not say what a whole one costs)."""
    last = rows[-1]
    cost = train_per_trace(last["seconds"]["train"], last["traces"])
    if last.get("train_stopped") and len(rows) > 1:
        cost = max(cost, train_cost(rows[:-1]))
    return cost


def _rounds(run: Run) -> list[dict[str, Any]]:
    stages = run.state["stages"]
    return [stages[k]["result"] for k in sorted(stages) if k.startswith("round_")]


def best_round(run: Run) -> dict[str, Any] | None:
    rows = _rounds(run)
    return max(rows, key=lambda x: (x["validation"], -x["round"])) if rows else None


def write_guide(run: Run) -> str | None:
    """OUT/guide.onnx: the best round's guide, tuned when a finished tuning tuned it."""
    from ngpm_compiler.experiments.learn_report import tuned_result

    best = best_round(run)
    tuned = tuned_result(run.state["stages"], best["round"] if best else None)
    src = tuned["guide"] if tuned else (best or {}).get("guide")
    if src is None:
        return None
    dst = run.out / "guide.onnx"
    atomic_write(dst, Path(src).read_bytes())
    return str(dst)


def run_rounds(run: Run, p: Plan) -> bool:
    """The guided rounds while the plan has them and the next one fits (its cost estimated
    from the measured rounds, keeping tuning's and the curve's share); a round that does
    not fit whole runs when MIN_TRACES of its traces fit (it stops recording at its share
    of the budget, as any round does); False when one was skipped for want of time."""
    for r in range(1, p.last_round + 1):
        name = f"round_{r:02d}"
        if name not in run.state["stages"]:
            room = run.clock.left() - _reserve(run, p)
            est = _next_round_estimate(run, p, r)
            if est > room:
                costs, val = _round_costs(run, p)
                n, particles = p.round_settings(r)
                fit = traces_that_fit(costs, particles, _rounds(run)[-1]["traces"], val, room)
                if fit < MIN_TRACES:
                    run.log(
                        f"round {r}: skipped: it would take about {_minutes(est)}, "
                        f"{_minutes(room)} are left before tuning"
                    )
                    notes = run.state.setdefault("notes", [])
                    said = f"round {r} skipped: "  # asked again (fill_rounds): said once
                    notes[:] = [x for x in notes if not x.startswith(said)]
                    notes.append(
                        f"{said}estimated {_minutes(est)}, "
                        f"{_minutes(room)} left before tuning and the curve"
                    )
                    return False
                run.log(
                    f"round {r}: about {min(fit, n)} of its {n} traces fit the "
                    f"{_minutes(room)} left before tuning: it records until its share"
                )
        run.stage(name, lambda r=r: round_stage(run, p, r))
        write_guide(run)
    return True


def fill_rounds(run: Run, p: Plan) -> Plan:
    """After the plan's rounds, rounds with a stronger teacher while the costs the rounds
    measured leave room for one before tuning and the curve (learn_plan.fill), each
    addition recorded as a stage fill_<e>_<k> (e: the extensions so far) and its rounds run."""
    e = len(extensions(run))
    k = 1
    while run_rounds(run, p):
        name = f"fill_{e}_{k}"
        if name not in run.state["stages"]:
            run.clock.check("planning more rounds")
            q = _fill_plan(run, p)
            if q is None:
                break
            run.log(f"plan: {q.reasons[-1]}")
            run.stage(name, lambda q=q: {"plan": asdict(q)})
        p = load_plan(run.state["stages"][name]["result"]["plan"])
        k += 1
    return p


def _fill_plan(run: Run, p: Plan) -> Plan | None:
    """The plan `p` with the strong rounds that fit the time left (None: none fits)."""
    if p.rounds == 0 or _rounds(run)[-1]["round"] < p.last_round:
        return None  # round 0 alone was planned (no guided costs), or a round was skipped
    costs, val = _round_costs(run, p)
    return fill(p, run.clock.left(), costs, _rounds(run)[-1]["traces"], val, _reserve(run, p))


def _round_costs(run: Run, p: Plan) -> tuple[Costs, float]:
    """The costs the last rounds measured, and one round's validation seconds (a guided
    round's validation also times the evaluation runs: round 0's includes start-up)."""
    rows = _rounds(run)
    last = rows[-1]
    costs = _costs(run)
    guided = [x["seconds_per_particle"] for x in rows if x["round"] > 0]
    costs = replace(
        costs,
        guided=guided[-1] if guided else costs.guided,
        train=train_cost(rows),
    )
    val = last["seconds"]["validation"] or validation_seconds(costs, p.val_targets, p.val_repeats)
    if last["round"] > 0 and last["seconds"]["validation"]:
        runs = costs.sets * p.val_targets * p.val_repeats
        costs = replace(costs, val_run=val * max(1, costs.workers) / max(1, runs))
    return costs, val


def _reserve(run: Run, p: Plan) -> float:
    """Seconds kept for tuning and the curve: the plan's estimates until a guided round
    has measured them anew (learn_plan.reserve_seconds), then the smaller of the two."""
    planned = p.estimates.get("tune", 0.0) + p.estimates.get("curve", 0.0)
    rows = _rounds(run)
    if not rows or rows[-1]["round"] == 0:
        return planned
    costs, val = _round_costs(run, p)
    curve_done = any(k.startswith("curve") for k in run.state["stages"])
    return min(planned, reserve_seconds(p, costs, val, curve_done))


def _next_round_estimate(run: Run, p: Plan, r: int) -> float:
    """Guided round r's seconds at the costs the last rounds measured."""
    costs, val = _round_costs(run, p)
    n, particles = p.round_settings(r)
    trained = _rounds(run)[-1]["traces"] + n
    return round_seconds(costs, n, particles, True, trained, val)


# --------------------------------------------------------------------------- tune, curve


def _tune(run: Run, p: Plan, guide: str, out: Path, work: Path, repeats: int) -> dict[str, Any]:
    """learning/tune.py's grid of the plan (choice temperatures x ESS thresholds; a grammar
    without choices: temperatures) for `guide` on the validation targets, into `out`."""
    from ngpm_runtime.inference.sitekinds import KINDS

    from ngpm_compiler.language.compile import load_grammar
    from ngpm_compiler.learning.tune import grid, tune

    grammar = run.state["stages"]["diagnose"]["result"]["grammar"]
    sites = load_grammar(grammar).sites
    if any(not KINDS[s.kind].continuous for s in sites):
        settings = grid((1.0,), p.choice_temperatures, p.ess)
    else:  # no choices to sharpen: the same number of continuous temperatures
        settings = grid(p.choice_temperatures, (1.0,), p.ess)
    return tune(
        grammar,
        guide,
        targets_of(run)["validation"],
        out,
        work,
        settings,
        k=p.val_targets,
        repeats=repeats,
        workers=run.cfg.workers,
        seed=run.cfg.seed,
        log=run.log,
        likelihood=run.cfg.likelihood,
    )


def tuned_teacher(run: Run, p: Plan, best: dict[str, Any]) -> tuple[str, str]:
    """With --tune-teachers: the best round's guide tuned as the final guide is (half the
    validation runs), the teacher of the next guided round, and its setting's label for the
    report. Made once per round (OUT/rounds/round_<r>/teacher.onnx; its tune runs cached).
    A teacher under the default settings can be weaker than round 0's unguided teacher
    (docs/3d.md, "Guided 3D growth")."""
    folder = Path(best["guide"]).parent
    out = folder / "teacher.onnx"
    if not p.choice_temperatures:
        return best["guide"], ""
    if not out.is_file():
        run.clock.check(f"tuning round {best['round']}'s guide as a teacher")
        _tune(run, p, best["guide"], out, folder / "teacher_tune", max(1, p.val_repeats // 2))
    from ngpm_compiler.jobs.backends import load_guide
    from ngpm_compiler.language.compile import load_grammar

    grammar = run.state["stages"]["diagnose"]["result"]["grammar"]
    label = load_guide(str(out), load_grammar(grammar)).settings.label()
    run.log(f"teacher: round {best['round']}'s guide tuned to {label} ({out})")
    return str(out), f", tuned {label}"


def tune_stage(run: Run, p: Plan) -> dict[str, Any] | None:
    """learning/tune.py on the best round's guide (None: no grid in the plan), into
    OUT/work/tuned.onnx (tuned_<k>.onnx when a rerun's extension k renewed tuning)."""
    best = best_round(run)
    if not p.choice_temperatures or best is None:
        return None
    tuned = f"tuned{final_suffix(run)}.onnx"
    res = _tune(
        run, p, best["guide"], run.out / "work" / tuned, run.out / "work" / "tune", p.val_repeats
    )
    return {
        "guide": str(run.out / "work" / tuned),
        "round": best["round"],
        "setting": res["best"].label(),
        "table": res["table"],
    }


def curve_stage(run: Run, p: Plan) -> list[dict[str, Any]]:
    """Similarity vs N of OUT/guide.onnx and of unguided SMC on the validation targets
    (every run cached, so a stop in the middle resumes)."""
    from ngpm_compiler.evaluation.heldout import run_heldout
    from ngpm_compiler.evaluation.runs import summarize

    t = targets_of(run)
    grammar = run.state["stages"]["diagnose"]["result"]["grammar"]
    rows: dict[tuple[Any, ...], dict[str, Any]] = {}
    ns = sorted(set(p.curve_guided))
    for i, n in enumerate(ns):
        run.clock.check("the curve")
        extra = tuple(x for x in p.curve_unguided if x not in ns) if i == len(ns) - 1 else ()
        res = run_heldout(
            run.out / "work" / "curve",
            grammar,
            t["validation"],
            {"guide": str(run.out / "guide.onnx")},
            k=p.val_targets,
            repeats=min(p.val_repeats, CURVE_REPEATS),
            guided_n=n,
            unguided_ns=extra,
            workers=run.cfg.workers,
            seed=run.cfg.seed + 1,
            log=lambda _m: None,
            likelihood=run.cfg.likelihood,
        )
        for row in res["rows"]:
            rows[(row["model"], row["dataset"], row["target"], row["n"], row["repeat"])] = row
    return summarize(list(rows.values()), "validation")


# --------------------------------------------------------------------------- the run


def learn(cfg: LearnConfig, log: Log = print) -> dict[str, Any]:
    """Run (or resume) every stage; returns {"guide", "report", "stopped", "state"}.
    "stopped" is None, or where the budget ran out (the best finished guide is written)."""
    from ngpm_compiler.experiments.learn_report import write_report

    if cfg.likelihood == "circuit" and cfg.targets:
        raise LearnError("the circuit likelihood has no targets: drop --targets")
    run = open_run(cfg, log)
    stopped = None
    try:
        _stages(run)
    except BudgetSpent as stop:
        stopped = stop.where
        run.state.setdefault("notes", []).append(f"budget spent during {stop.where}")
        log(f"budget of {_minutes(cfg.budget)} spent during {stop.where}")
    finally:
        run.save()
    guide = write_guide(run)
    if guide is None:
        raise LearnError(
            f"the budget of {_minutes(cfg.budget)} was spent during {stopped} before a guide "
            f"was trained; rerun with a larger --budget (the run resumes in {cfg.out})"
        )
    report = write_report(run.out, run.state, stopped)
    run.save()
    return {"guide": guide, "report": str(report), "stopped": stopped, "state": run.state}


def switch_targets(
    run: Run, d: dict[str, Any], t: dict[str, Any], reach: dict[str, Any]
) -> dict[str, Any]:
    """The targets to go on with: the grammar's envelopes when the generic targets (built
    without --targets) are out of reach and unguided SMC reaches the envelopes better, else
    `t` with the reach warning shown. Decided before the first measurement only, so a run
    resumed from an older learn.json does not change targets halfway."""
    if not reach["warning"]:
        return t
    stages = run.state["stages"]
    old = "envelopes" not in stages and "measure" in stages
    if t.get("kind", "generic") != "generic" or old or dim_of(run) == 3:
        run.log(reach["warning"])
        return t
    res = run.stage("envelopes", lambda: envelopes_stage(run, d, reach))
    run.log(res["line"])
    return targets_of(run)


def warm_kernels(run: Run) -> None:
    """Compile the SMC kernels first when their disk cache is cold (a fresh install or
    checkout), so that the reach and measure stages time runs, not compiles: a cold 3D run
    measured trace jobs 3x and `reach` 10x slower, and planned 685 round-0 traces for 70
    minutes where a warm one plans 1021 for 45."""
    from ngpm_runtime.warmup import cache_is_cold, warm_up

    if "measure" in run.state["stages"] or not cache_is_cold():
        return
    run.log("kernels: compiling them for this machine before the timed stages (once)")
    run.log(f"kernels: compiled in {warm_up():.0f} s")


def _stages(run: Run) -> None:
    warm_kernels(run)
    d = run.stage("diagnose", lambda: diagnose_stage(run))
    for line in d["lines"]:
        run.log(line)
    if d["viewport_proposed"]:
        run.log(f"grammar: {d['grammar']}, with the proposed viewport (use it with the guide)")
    t = run.stage("targets", lambda: targets_stage(run, d["grammar"]))
    if run.cfg.likelihood == "shape":
        reach = run.stage("reach", lambda: reach_stage(run, d, t["train"][0]))
        t = switch_targets(run, d, t, reach)
    run.clock.check("measuring")
    small = run.cfg.budget < 120
    particles = MEASURE_SMALL if small else UNGUIDED_PARTICLES
    m = run.stage("measure", lambda: measure_stage(run, d["grammar"], t["train"][0], particles))
    run.state.setdefault("costs", {}).update(unguided=m)
    p = load_plan(run.stage("plan", lambda: plan_stage(run)))
    run.stage("round_00", lambda: round_stage(run, p, 0))
    write_guide(run)
    room = run.clock.left() - p.estimates.get("tune", 0.0) - p.estimates.get("curve", 0.0)
    if p.rounds > 0 or "replan" in run.state["stages"] or room > REPLAN_ROOM:
        run.clock.check("measuring guided SMC")
        p = load_plan(run.stage("replan", lambda: replan_stage(run, p)))
    p = extended(run, p)
    p = fill_rounds(run, p)
    run.clock.check("tuning")
    sfx = final_suffix(run)
    if p.estimates.get("tune", 0.0) > run.clock.left():
        run.state.setdefault("notes", []).append("tuning skipped: too little budget left")
    else:
        run.stage(f"tune{sfx}", lambda: tune_stage(run, p))
        write_guide(run)
    run.stage(f"curve{sfx}", lambda: curve_stage(run, p))
