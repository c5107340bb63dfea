"""Grammar diagnostics before spending compute (`ngpmc check`): estimates from forward
samples and a warning for rules whose chains branch without end.

- Forward samples: `n` independent prior samples (batched SMC runs without a likelihood,
  which never resample), in batches until a time budget is spent: primitives per sample,
  the samples stopped by a cap (max primitives, max modules, or the time cap: a batch still
  running after `hard_cap` seconds, counted as runaway), and the box their primitives span.
- Time of one 600-particle SMC run: one unguided run into the bundled demo horse (what
  `ngpmc grow` and trace recording run), measured when it ends within the time budget;
  else stopped there and its time scaled by the steps of the longest forward sample over
  the steps it made (SMC takes one step per primitive until its longest particle ends): a
  rough estimate, for telling seconds from minutes.
- Branching: the mean matrix of the grammar's productions (expected copies of each module
  a rule's successor holds, over its alternatives' probabilities; a rule with conditions
  counts its most prolific group, as if that condition held). A loop of rules whose mean
  matrix has spectral radius above 1 is a supercritical branching process: its chains fork
  more than once per generation on average and grow without end unless a condition or the
  derivation length stops them. That alone is no fault (the bush's fork stops by its
  length condition, the ABOP plant by its derivation length), so the warning needs the
  samples to show it: some of them stopped at a cap.
- Viewport: for a grammar without `viewport:`, the square box of the samples' primitives,
  padded and rounded outward, as a header line to paste.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from ngpm_runtime.errors import printable
from ngpm_runtime.inference.smc import SMCObserver
from ngpm_runtime.program import Program

from ngpm_compiler.language.checker import Alt, Checked
from ngpm_compiler.language.compile import CompiledGrammar

SAMPLE_BATCH = 10  # forward samples per batched run
TARGET_N = 600  # particles of the run whose time is estimated
TIMING_TARGET = "horse"  # the bundled demo picture it grows into
RUNAWAY = "time cap"  # what a batch stopped by the hard time cap counts as


class TimeUp(Exception):
    """Raised by Deadline to end a run that took too long."""


class Deadline(SMCObserver):
    """An SMC observer that ends the run once `perf_counter()` passes `at`."""

    def __init__(self, at: float) -> None:
        self.at = at

    def step_done(self, state: Any) -> None:
        if time.perf_counter() > self.at:
            raise TimeUp


@dataclass
class Samples:
    """What forward samples show."""

    primitives: list[int] = field(default_factory=list)  # per finished sample
    limits: dict[str, int] = field(default_factory=dict)  # cap -> samples it stopped
    box: tuple[float, float, float, float] | None = None  # xmin, xmax, ymin, ymax
    seconds: float = 0.0

    @property
    def n(self) -> int:
        """Samples drawn, those a time cap stopped included."""
        return len(self.primitives) + self.limits.get(RUNAWAY, 0)

    @property
    def capped(self) -> int:
        return sum(self.limits.values())


def forward_samples(
    program: Program, n: int = 40, budget: float = 2.0, hard_cap: float = 8.0, seed: int = 0
) -> Samples:
    """Up to `n` prior samples in batches of SAMPLE_BATCH, stopping at the first batch that
    ends after `budget` seconds; a batch still running at `hard_cap` seconds is stopped and
    its samples count as stopped by the time cap."""
    from ngpm_runtime.image.raster import bbox_of
    from ngpm_runtime.inference.smc import SMCOptions, smc

    out = Samples()
    box = np.array([np.inf, -np.inf, np.inf, -np.inf])
    t0 = time.perf_counter()
    for b in range(math.ceil(n / SAMPLE_BATCH)):
        size = min(SAMPLE_BATCH, n - b * SAMPLE_BATCH)
        # equal weights (no likelihood) keep the ESS at N: no resampling, independent samples
        options = SMCOptions(seed=(seed + b) % 2**63, ess_threshold=0.5)
        try:
            res = smc(program, None, size, options=options, observers=[Deadline(t0 + hard_cap)])
        except TimeUp:
            out.limits[RUNAWAY] = out.limits.get(RUNAWAY, 0) + size
            break
        for p in res.particles:
            out.primitives.append(len(p.primitives))
            if p.status == "limit" and p.limit:
                out.limits[p.limit] = out.limits.get(p.limit, 0) + 1
            if p.primitives and program.dim == 2:  # a 3D grammar's box is its own header
                xmin, ymin, xmax, ymax = bbox_of(p.primitives)
                box = np.array(
                    [min(box[0], xmin), max(box[1], xmax), min(box[2], ymin), max(box[3], ymax)]
                )
        if time.perf_counter() - t0 > budget:
            break
    out.seconds = time.perf_counter() - t0
    if np.isfinite(box).all():
        out.box = (float(box[0]), float(box[1]), float(box[2]), float(box[3]))
    return out


def propose_viewport(
    box: tuple[float, float, float, float], pad: float = 0.05
) -> tuple[float, float, float, float]:
    """A square viewport (targets are square) holding `box` with `pad` of its side on each
    side, its edges rounded outward to a round step (a tenth of the side's power of ten)."""
    xmin, xmax, ymin, ymax = box
    side = max(xmax - xmin, ymax - ymin, 1e-6) * (1 + 2 * pad)
    cx, cy = (xmin + xmax) / 2, (ymin + ymax) / 2
    step = 10.0 ** math.floor(math.log10(side)) / 10
    if side / step < 20:  # so a side of 1.2 rounds to tenths, not to whole units
        step /= 2

    def down(v: float) -> float:
        return round(math.floor(v / step) * step, 10)

    def up(v: float) -> float:
        return round(math.ceil(v / step) * step, 10)

    x0, x1 = down(cx - side / 2), up(cx + side / 2)
    y0, y1 = down(cy - side / 2), up(cy + side / 2)
    grow_x, grow_y = max(0.0, (y1 - y0) - (x1 - x0)), max(0.0, (x1 - x0) - (y1 - y0))
    # rounding may leave one side a step longer: widen the other to keep it square
    return x0 - grow_x / 2, x1 + grow_x / 2, y0 - grow_y / 2, y1 + grow_y / 2


def viewport_line(viewport: tuple[float, float, float, float]) -> str:
    return "viewport: " + " ".join(f"{round(v, 6):g}" for v in viewport)


class StepCount(Deadline):
    """A Deadline that also counts the run's steps."""

    def __init__(self, at: float) -> None:
        super().__init__(at)
        self.steps = 0

    def step_done(self, state: Any) -> None:
        self.steps = state.steps
        super().step_done(state)


@dataclass
class Timing:
    seconds: float  # the estimate for one TARGET_N-particle run
    measured: float  # the seconds the timed run took (until the cap, if it hit it)
    steps: int  # its steps
    scaled_to: int = 0  # steps it was scaled to when the cap stopped it (0: it finished)

    @property
    def lower_bound(self) -> bool:
        """The cap stopped the run past the longest sample's steps: `seconds` is a floor."""
        return 0 < self.scaled_to <= self.steps


def smc_time(program: Program, longest: int, budget: float = 3.0) -> Timing:
    """One unguided SMC run at TARGET_N into the bundled demo horse (what `ngpmc grow` and
    trace recording run), stopped at `budget` seconds; a stopped run's time is scaled by
    `longest` (the steps of the longest forward sample, one per primitive) over its steps
    so far, as SMC runs until its longest particle ends (a lower bound when it made more
    steps than that already). The grammar's compiled deriver, which such a run uses, is
    compiled (or loaded) first, outside the timing."""
    from ngpm_runtime.bundled import demo_targets
    from ngpm_runtime.geometry.compiled import compiled_deriver
    from ngpm_runtime.grow import grow

    target = {t.name: t for t in demo_targets()}[TIMING_TARGET]
    compiled_deriver(program)  # compiled before the clock starts: once per grammar, cached
    count = StepCount(time.perf_counter() + budget)
    start = time.perf_counter()
    try:
        res = grow(program, target, None, TARGET_N, seed=0, observers=[count])
    except TimeUp:
        spent = time.perf_counter() - start
        scale = max(1.0, longest / max(count.steps, 1))
        return Timing(spent * scale, spent, count.steps, max(longest, count.steps))
    return Timing(res.seconds, res.seconds, res.smc.steps)


# --------------------------------------------------------------------------- branching


@dataclass
class Branching:
    """A loop of rules whose chains fork more than once per generation on average."""

    rate: float  # mean offspring per generation (spectral radius of the loop's mean matrix)
    modules: list[str]  # the loop's modules
    pred: str  # the rule to look at: where the loop forks most
    line: int  # its line (the alternative with the most copies)


def _alt_counts(alt: Alt, names: list[str]) -> np.ndarray:
    index = {m: i for i, m in enumerate(names)}
    row = np.zeros(len(names))
    for r in alt.modules:
        if r.name in index:
            row[index[r.name]] += 1
    return row


def mean_matrix(checked: Checked) -> tuple[list[str], np.ndarray]:
    """(module names with productions, M): M[i, j] = expected copies of module j in the
    successor of module i, from the production probabilities; of several condition groups,
    each entry takes the most prolific group's (conditions are not evaluated)."""
    names = sorted(checked.productions)
    m = np.zeros((len(names), len(names)))
    for i, name in enumerate(names):
        for group in checked.productions[name].groups:
            row = sum(
                (_alt_counts(a, names) * (1.0 if a.prob is None else a.prob) for a in group.alts),
                np.zeros(len(names)),
            )
            m[i] = np.maximum(m[i], row)
    return names, m


def _loops(m: np.ndarray, start: np.ndarray) -> list[list[int]]:
    """Strongly connected components of the graph i -> j where m[i, j] > 0 that hold a
    cycle (several nodes, or one with a self loop) and that the nodes `start` (bool) reach."""
    n = len(m)
    closure = m > 0
    for k in range(n):  # Warshall: closure[i, j] = j reachable from i in >= 1 step
        closure |= closure[:, k : k + 1] & closure[k : k + 1, :]
    reached = start | closure[start].any(axis=0)
    seen: set[int] = set()
    out = []
    for i in range(n):
        if i in seen or not closure[i, i] or not reached[i]:
            continue
        comp = [j for j in range(n) if closure[i, j] and closure[j, i]]
        seen.update(comp)
        out.append(comp)
    return out


def supercritical(checked: Checked) -> list[Branching]:
    """The loops of rules with mean offspring per generation above 1, fastest first."""
    names, m = mean_matrix(checked)
    axiom = {r.name for r in checked.axiom}
    found = []
    for comp in _loops(m, np.array([name in axiom for name in names], dtype=bool)):
        sub = m[np.ix_(comp, comp)]
        rate = float(max(abs(np.linalg.eigvals(sub))))
        if rate <= 1 + 1e-9:
            continue
        # the rule to look at: the one that makes the most copies of loop modules
        i = max(comp, key=lambda k: (float(m[k, comp].sum()), -k))
        loop = [names[k] for k in comp]
        best: tuple[float, int] = (-1.0, 0)
        for group in checked.productions[names[i]].groups:
            for alt in group.alts:
                copies = float(_alt_counts(alt, names)[comp].sum())
                if copies > best[0]:
                    best = (copies, alt.rule.line)
        found.append(Branching(rate, loop, names[i], best[1]))
    return sorted(found, key=lambda b: -b.rate)


# --------------------------------------------------------------------------- report


@dataclass
class Diagnosis:
    filename: str
    program: Program
    branching: list[Branching]
    samples: Samples | None = None
    viewport: tuple[float, float, float, float] | None = None  # proposed (none in the file)
    timing: Timing | None = None


def diagnose(
    compiled: CompiledGrammar,
    samples: int = 40,
    seed: int = 0,
    budget: float = 2.0,
    time_smc: float = 3.0,
) -> Diagnosis:
    """Branching from the grammar; with `samples` > 0, forward samples (for about `budget`
    seconds; a batch still running at 4x `budget`, 8 s at least, counts as runaway), a
    proposed viewport (when the grammar has none) and, with `time_smc` > 0, the time of one
    600-particle SMC run (measured for at most `time_smc` seconds)."""
    program = compiled.program()
    diag = Diagnosis(compiled.filename, program, supercritical(compiled.checked))
    if samples <= 0:
        return diag
    s = diag.samples = forward_samples(
        program, samples, budget=budget, hard_cap=max(8.0, 4 * budget), seed=seed
    )
    if program.viewport is None and s.box is not None:
        diag.viewport = propose_viewport(s.box)
    viewport = program.viewport or diag.viewport
    # grow draws into the picture through the viewport; 3D grammars grow into no picture
    if time_smc > 0 and viewport is not None and program.dim == 2:
        longest = program.max_primitives if s.limits.get(RUNAWAY) else max(s.primitives)
        diag.timing = smc_time(replace(program, viewport=viewport), longest, time_smc)
    return diag


def _caps_text(s: Samples, program: Program) -> str:
    if not s.capped:
        return f"none of {s.n}"
    names = {
        "max primitives": f"max primitives ({program.max_primitives})",
        RUNAWAY: "runaway (still running at the time cap)",
    }
    parts = [f"{k} at {names.get(cap, cap)}" for cap, k in sorted(s.limits.items())]
    return f"{s.capped} of {s.n} ({100 * s.capped / s.n:.0f}%): " + ", ".join(parts)


def sample_lines(diag: Diagnosis) -> list[str]:
    """The estimates' lines (forward samples, caps, SMC time, proposed viewport)."""
    s, program = diag.samples, diag.program
    if s is None:
        return []
    lines = [f"forward samples: {s.n} in {s.seconds:.1f} s"]
    if s.primitives:
        prims = np.array(s.primitives)
        lines.append(
            f"  primitives per sample: median {np.median(prims):.0f}, "
            f"p90 {np.percentile(prims, 90):.0f}, max {prims.max()}"
        )
    lines.append(f"  samples stopped by a cap: {_caps_text(s, program)}")
    t = diag.timing
    if t is not None:
        run, about = f"unguided into the demo {TIMING_TARGET}", "about"
        if t.lower_bound:
            how, about = f"{run}: still running after {t.steps} steps, stopped", "more than"
        elif t.scaled_to:
            how = (
                f"{run}: {t.steps} steps in {t.measured:.1f} s, then stopped; scaled to "
                f"{t.scaled_to} steps, as the longest forward sample drew {t.scaled_to} "
                "primitives"
            )
        else:
            how = f"{run}, measured: {t.steps} steps"
        lines.append(f"  one {TARGET_N}-particle SMC run: {about} {_duration(t.seconds)} ({how})")
    if diag.viewport is not None:
        lines.append(
            f"  no 'viewport:' line: the samples span {_box_text(s.box)}; "
            "add this header line (commands that draw into targets need one):"
        )
        lines.append(f"    {viewport_line(diag.viewport)}")
    elif program.viewport is None:
        lines.append("  no 'viewport:' line, and the samples draw nothing to propose one from")
    return lines


def _box_text(box: tuple[float, float, float, float] | None) -> str:
    if box is None:
        return "nothing"
    return f"x {box[0]:.3g} to {box[1]:.3g}, y {box[2]:.3g} to {box[3]:.3g}"


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.2g} s" if seconds < 10 else f"{seconds:.0f} s"
    return f"{seconds / 60:.0f} min"


def warning_lines(diag: Diagnosis) -> list[str]:
    """One line per problem: a supercritical loop of rules when samples ran to a cap (a
    note when there are no samples to tell), or samples at a cap with no such loop."""
    s, out, name = diag.samples, [], printable(diag.filename)
    for b in diag.branching:
        head = (
            f"{name}:{b.line}: rule {b.pred} branches supercritically: chains "
            f"of {', '.join(b.modules)} fork into {b.rate:.2f} per generation on average"
        )
        if s is None:
            out.append(
                f"note: {head}, so only a condition or the derivation length ends "
                "them (without --no-samples, check shows whether samples reach a cap)"
            )
        elif s.capped:
            out.append(
                f"warning: {head} (above 1: they grow without end), and {s.capped} of "
                f"{s.n} samples ran to a cap; make it fork less often, or end its "
                "chains with a condition"
            )
    if s is not None and s.capped and not diag.branching:
        out.append(
            f"warning: {name}: {s.capped} of {s.n} samples ran to a cap (see "
            "above): the grammar does not end by itself; add a 'derivation length:' "
            "or a condition that ends it"
        )
    return out


def hint_lines(diag: Diagnosis, checked: Checked) -> list[str]:
    """A hint when the grammar has no 'turtle arguments:' line and some random turtle
    arguments are drawn before the turtle reaches them (docs/language.md, section 6)."""
    if checked.lazy is not None or not checked.late_sites:
        return []
    sites = [diag.program.sites[i] for i in checked.late_sites]
    shown = ", ".join(f"{s.source} at line {s.line}:{s.col}" for s in sites[:3])
    more = f" and {len(sites) - 3} more" if len(sites) > 3 else ""
    return [
        f"hint: {printable(diag.filename)}: {len(sites)} random turtle argument"
        f"{'s are' if len(sites) > 1 else ' is'} drawn when the rule fires, before the turtle "
        f"gets there ({shown}{more}); 'turtle arguments: lazy' draws them where the turtle "
        "turns, and SMC and a guide see what was drawn before (docs/language.md, section 6)"
    ]


# --------------------------------------------------------------------------- reachability

REACH_N = 600  # particles of the reachability runs (round 0's teacher)
REACH_N_3D = 100  # a 3D grammar's (3D runs cost more per particle; the 3D guide's teacher)
REACH_TARGETS = 3  # training targets it runs on
# below this mean similarity unguided SMC reaches the targets too poorly for a guide to learn
# from: on learn's scribbles and varied targets ivy, lily and vines reach 0.3 and more at
# N = 600, the bush (a small bounded shape growing up) 0.05 (docs/results/learn_grammars.md)
REACH_LOW = 0.15


@dataclass
class Reach:
    """What unguided SMC reaches on a few targets: the best particle's similarity, and the
    share of the canvas its drawing and the target's ink cover (means over the targets;
    a 3D grammar's: of the box's voxels)."""

    n: int
    targets: list[str]
    similarity: float
    drawn: float  # share of the canvas the best particles draw on
    ink: float  # share of the canvas the targets' ink covers
    covered: float  # share of the targets' ink the best particles draw on
    seconds: float
    dim: int = 2

    @property
    def low(self) -> bool:
        return self.similarity < REACH_LOW


def reachability(program: Program, targets: list[Any], n: int = REACH_N, seed: int = 0) -> Reach:
    """Unguided SMC with n particles into each of `targets` (2D shape targets, or a 3D
    grammar's VolumeTargets: the best tree's voxels against the occupancy)."""
    from ngpm_runtime.grow import grow

    sims, drawn, ink, covered = [], [], [], []
    t0 = time.perf_counter()
    for i, target in enumerate(targets):
        res = grow(program, target, None, n, seed + i)
        ink_of = target.occupancy if program.dim == 3 else target.mask
        img, mask = np.asarray(res.image) > 0, np.asarray(ink_of) > 0
        sims.append(res.similarity)
        drawn.append(float(img.mean()))
        ink.append(float(mask.mean()))
        covered.append(float((img & mask).sum() / max(1, mask.sum())))
    return Reach(
        n,
        [t.name for t in targets],
        float(np.mean(sims)),
        float(np.mean(drawn)),
        float(np.mean(ink)),
        float(np.mean(covered)),
        time.perf_counter() - t0,
        program.dim,
    )


# the words of the reach warning: 2D (canvas, ink) and 3D (box, voxels)
_REACH_WORDS = {
    2: {
        "seen": "its best drawings cover {drawn:.0%} of the canvas and {covered:.0%} of the "
        "targets' ink, which covers {ink:.0%}",
        "small": "it draws too small or too little for these targets: fit the viewport to what "
        "it draws, lengthen the derivation, or train on targets of its size (--targets)",
        "big": "it draws over more than the targets hold: widen the viewport, draw thinner or "
        "fewer strokes, or train on fuller targets (--targets)",
    },
    3: {
        "seen": "its best trees fill {drawn:.0%} of the box and {covered:.0%} of the targets' "
        "voxels, which fill {ink:.0%}",
        "small": "it grows too small or too little for these targets: fit the box "
        "('viewport:') to what it grows, lengthen the derivation, or train on other targets "
        "(--targets)",
        "big": "it grows over more than the targets hold: widen the box, grow thinner or fewer "
        "branches, or train on fuller targets (--targets)",
    },
}


def reach_seen(drawn: float, covered: float, ink: float, dim: int = 2) -> str:
    """'its best drawings cover ...': what the best particles and the targets cover, in the
    words of the grammar's dimension (canvas and ink, or box and voxels)."""
    return _REACH_WORDS[dim]["seen"].format(drawn=drawn, covered=covered, ink=ink)


def reach_line(r: Reach, filename: str) -> str:
    """The one-line warning for a grammar unguided SMC reaches the targets poorly with: the
    cause in numbers and what to change."""
    words = _REACH_WORDS[r.dim]
    fix = words["small"] if r.drawn < r.ink else words["big"]
    return (
        f"warning: {printable(filename)}: unguided SMC with {r.n} particles reaches similarity "
        f"{r.similarity:.3f} on {len(r.targets)} training targets (below {REACH_LOW}: too "
        f"little for a guide to learn from): {reach_seen(r.drawn, r.covered, r.ink, r.dim)}; "
        f"{fix}"
    )
