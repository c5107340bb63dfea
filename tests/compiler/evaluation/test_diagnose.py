"""Grammar diagnostics (`ngpmc check`): branching from the production probabilities, forward
samples, caps, the proposed viewport and the SMC time estimate."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from fixtures.datasets import make_dataset
from fixtures.grammars import BOUNDED, EXPLODING, EXPLODING_LINE, LOOP, REACHES_BARS, SPECK
from repo_paths import REPO

from ngpm_compiler.evaluation.diagnose import (
    REACH_LOW,
    RUNAWAY,
    Reach,
    diagnose,
    forward_samples,
    hint_lines,
    mean_matrix,
    propose_viewport,
    reach_line,
    reachability,
    sample_lines,
    smc_time,
    supercritical,
    viewport_line,
    warning_lines,
)
from ngpm_compiler.language.compile import compile_grammar, load_grammar

NO_VIEWPORT = BOUNDED.replace("viewport: -10 10 -2 18\n", "")


def compiled(tmp_path: Path, text: str, name: str = "g.lsys"):
    path = tmp_path / name
    path.write_text(text)
    return compile_grammar(path, filename=str(path))


def test_the_mean_matrix_holds_the_production_probabilities(tmp_path: Path) -> None:
    names, m = mean_matrix(compiled(tmp_path, EXPLODING).checked)
    assert names == ["A"] and m[0, 0] == pytest.approx(1.8)
    names, m = mean_matrix(compiled(tmp_path, LOOP).checked)
    assert names == ["B", "K"]
    assert m.ravel().tolist() == pytest.approx([0.0, 3.0, 0.7, 0.0])


def test_supercritical_loops_name_the_rule_that_forks(tmp_path: Path) -> None:
    (b,) = supercritical(compiled(tmp_path, EXPLODING).checked)
    assert (b.pred, b.line, b.modules) == ("A", EXPLODING_LINE, ["A"])
    assert b.rate == pytest.approx(1.8)
    (b,) = supercritical(compiled(tmp_path, LOOP).checked)
    assert (b.pred, b.line, b.modules) == ("B", 10, ["B", "K"])
    assert b.rate == pytest.approx(math.sqrt(3 * 0.7))
    # a loop the axiom never reaches is no concern
    unreached = LOOP.replace("Axiom: B", "Axiom: F")
    assert supercritical(compiled(tmp_path, unreached).checked) == []


def test_an_exploding_grammar_gets_one_warning_naming_the_rule(tmp_path: Path) -> None:
    c = compiled(tmp_path, EXPLODING, "explode.lsys")
    diag = diagnose(c, samples=20, budget=60, time_smc=0)
    s = diag.samples
    assert s is not None and s.n == 20 and s.capped == s.limits["max primitives"] > 0
    assert max(s.primitives) == 600 and min(s.primitives) < 600
    (line,) = warning_lines(diag)
    assert line.startswith(
        f"warning: {c.filename}:{EXPLODING_LINE}: rule A branches "
        "supercritically: chains of A fork into 1.80 per generation"
    )
    assert f"{s.capped} of {s.n} samples ran to a cap" in line
    text = "\n".join(sample_lines(diag))
    assert f"samples stopped by a cap: {s.capped} of {s.n}" in text
    assert "at max primitives (600)" in text


def test_a_bounded_fork_gets_no_warning(tmp_path: Path) -> None:
    c = compiled(tmp_path, BOUNDED)
    diag = diagnose(c, samples=20, time_smc=0)
    assert diag.branching and diag.samples is not None and diag.samples.capped == 0
    assert warning_lines(diag) == []
    # without samples nothing tells, so it is a note, not a warning
    quiet = diagnose(c, samples=0)
    (line,) = warning_lines(quiet)
    assert line.startswith("note: ") and "rule A branches supercritically" in line
    assert sample_lines(quiet) == []


@pytest.mark.parametrize(
    "grammar", sorted((REPO / "grammars").glob("*.lsys")), ids=lambda p: p.name
)
def test_the_shipped_grammars_get_no_warning(grammar: Path) -> None:
    c = compile_grammar(grammar, filename=str(grammar))
    # a generous budget: a loaded machine must not push a batch past the time cap
    diag = diagnose(c, samples=20, budget=10.0, time_smc=0)
    assert diag.samples is not None and diag.samples.capped == 0
    assert [x for x in warning_lines(diag) if x.startswith("warning")] == []


def test_samples_at_a_cap_without_a_supercritical_rule_are_a_warning(tmp_path: Path) -> None:
    endless = (
        "viewport: -5 5 -1 9\nderivation length: 1000\nmax primitives: 50\n"
        "Axiom: A\nproduction:\n"
        "A --> F A\nendlsystem\n"
    )
    c = compiled(tmp_path, endless)
    diag = diagnose(c, samples=5, time_smc=0)
    assert diag.branching == []
    (line,) = warning_lines(diag)
    assert line.startswith(f"warning: {c.filename}: 5 of 5 samples ran to a cap")


def test_a_batch_past_the_time_cap_counts_as_runaway(tmp_path: Path) -> None:
    program = compiled(tmp_path, EXPLODING).program()
    s = forward_samples(program, n=25, hard_cap=0.0)
    assert s.primitives == [] and s.limits == {RUNAWAY: 10} and s.n == 10 == s.capped


def test_forward_samples_are_seeded(tmp_path: Path) -> None:
    program = compiled(tmp_path, BOUNDED).program()
    a, b = (forward_samples(program, n=15, budget=60, seed=3) for _ in range(2))
    assert len(a.primitives) == 15 and a.primitives == b.primitives and a.box == b.box
    assert len(set(a.primitives)) > 1  # independent samples, not copies of one


def test_propose_viewport_is_square_padded_and_round() -> None:
    assert propose_viewport((0.0, 10.0, 0.0, 5.0)) == (-0.5, 10.5, -3.0, 8.0)
    for box in [(-17.2, 6.46, -23.0, -9.25), (0.01, 0.03, 5.0, 5.9), (-400, 700, 3, 90)]:
        x0, x1, y0, y1 = propose_viewport(box)
        assert x0 < box[0] and x1 > box[1] and y0 < box[2] and y1 > box[3]
        assert x1 - x0 == pytest.approx(y1 - y0)
        assert len(viewport_line((x0, x1, y0, y1))) < 40  # round numbers, short to paste


def test_a_grammar_without_viewport_gets_one_proposed(tmp_path: Path) -> None:
    c = compiled(tmp_path, NO_VIEWPORT)
    diag = diagnose(c, samples=20, time_smc=0)
    assert diag.viewport is not None and diag.samples is not None
    box = diag.samples.box
    assert box is not None
    x0, x1, y0, y1 = diag.viewport
    assert x0 < box[0] and x1 > box[1] and y0 < box[2] and y1 > box[3]
    lines = sample_lines(diag)
    assert lines[-1] == "    " + viewport_line(diag.viewport)
    # pasted into the grammar, it is the grammar's viewport and nothing more is proposed
    fixed = compiled(tmp_path, viewport_line(diag.viewport) + "\n" + NO_VIEWPORT, "fixed.lsys")
    assert fixed.program().viewport == pytest.approx(diag.viewport)
    again = diagnose(fixed, samples=5, time_smc=0)
    assert again.viewport is None and "viewport" not in "\n".join(sample_lines(again))


def test_smc_time_measures_a_short_run_and_scales_a_stopped_one() -> None:
    c = compile_grammar(REPO / "grammars" / "chain.lsys")
    program = c.program()
    t = smc_time(program, longest=12, budget=60.0)
    assert t.scaled_to == 0 and t.steps == 12 and t.seconds == t.measured > 0
    t = smc_time(program, longest=12, budget=0.0)  # stopped at its first step
    assert t.steps == 1 and t.scaled_to == 12 and not t.lower_bound
    assert t.seconds == pytest.approx(t.measured * 12)
    t = smc_time(program, longest=1, budget=0.0)  # past the longest sample: a floor
    assert t.lower_bound and t.seconds == t.measured


def test_the_api_docs_show_the_exploding_grammar_of_these_tests() -> None:
    text = (REPO / "docs" / "api.md").read_text(encoding="utf-8")
    assert f"```\n{EXPLODING}```" in text
    assert f"warning: explode.lsys:{EXPLODING_LINE}: rule A branches" in text


def bars(tmp_path: Path) -> list:
    from ngpm_runtime.image.targets import load_dataset

    return load_dataset(str(make_dataset(tmp_path / "bars", 3)), size=50)


def test_a_grammar_that_cannot_reach_the_targets_is_low_and_says_why(tmp_path):
    r = reachability(load_grammar("speck.lsys", SPECK), bars(tmp_path), n=10)
    assert r.low and r.similarity < REACH_LOW and r.n == 10 and len(r.targets) == 3
    assert r.drawn < r.ink and r.covered < 0.1
    line = reach_line(r, "speck.lsys")
    assert line.startswith("warning: speck.lsys: unguided SMC with 10 particles reaches ")
    assert "draws too small or too little" in line and "\n" not in line
    assert f"cover {r.drawn:.0%} of the canvas and {r.covered:.0%} of the targets' ink" in line


def test_a_3d_grammar_reaches_voxels_and_its_warning_speaks_of_the_box():
    """reachability of a 3D grammar into VolumeTargets compares the best tree's voxels with
    the occupancy; the warning names the box and its fix."""
    from ngpm_runtime.volume.target import VolumeTarget

    program = load_grammar(str(REPO / "grammars" / "topiary3d.lsys"))
    occ = np.zeros((16, 16, 16), bool)
    occ[4:12, 2:14, 4:12] = True
    lo, hi = np.array(program.box[::2]), np.array(program.box[1::2])
    voxel = float((hi - lo).max()) / 16
    target = VolumeTarget(occ, lo, voxel, np.array([0.0, lo[1], 0.0]), name="block")
    r = reachability(program, [target], n=4)
    assert r.dim == 3 and r.targets == ["block"] and 0 < r.drawn < 1
    assert r.ink == pytest.approx(occ.mean()) and 0 <= r.covered <= 1
    small = Reach(100, ["a"], 0.05, 0.02, 0.2, 0.05, 1.0, dim=3)
    line = reach_line(small, "shrub.lsys")
    assert "its best trees fill 2% of the box and 5% of the targets' voxels, which fill 20%" in line
    assert "grows too small" in line and "'viewport:'" in line and "\n" not in line
    big = Reach(100, ["a"], 0.05, 0.5, 0.2, 0.9, 1.0, dim=3)
    assert "grows over more than the targets hold" in reach_line(big, "shrub.lsys")


def test_a_grammar_that_reaches_the_targets_is_not_low(tmp_path):
    r = reachability(load_grammar("thick.lsys", REACHES_BARS), bars(tmp_path), n=10)
    assert not r.low and r.similarity > 2 * REACH_LOW and r.covered > 0.5


FORK = """viewport: -5 5 -1 9
derivation length: 8
{line}
Axiom: A(1)
production:
A(l) : l > 0.3 --> F(l) [ +(gauss(30, 8)) A(l * 0.7) ] [ -(gauss(30, 8)) A(l * 0.7) ]
endlsystem
"""


def test_a_hint_names_turtle_arguments_drawn_before_the_turtle_gets_there(tmp_path) -> None:
    c = compiled(tmp_path, FORK.format(line=""))
    (hint,) = hint_lines(diagnose(c, samples=0), c.checked)
    assert hint.startswith(f"hint: {tmp_path / 'g.lsys'}: 2 random turtle arguments are drawn")
    assert "gauss(30, 8) at line 6:29" in hint and "'turtle arguments: lazy'" in hint
    # a grammar that says either way, or whose random turns come first, gets none
    for line in ("turtle arguments: lazy", "turtle arguments: eager"):
        c = compiled(tmp_path, FORK.format(line=line))
        assert hint_lines(diagnose(c, samples=0), c.checked) == []
    chain = REPO / "grammars" / "chain.lsys"
    c = compile_grammar(chain, filename=str(chain))
    assert hint_lines(diagnose(c, samples=0), c.checked) == []
