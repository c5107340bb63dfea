"""grow.py: the likelihood a run is built with."""

from __future__ import annotations

import numpy as np
import pytest
from fixtures.tiny_programs import make_program
from ngpm_runtime.errors import NgpmError
from ngpm_runtime.grow import make_likelihood
from ngpm_runtime.image.targets import Target


@pytest.mark.parametrize("kind", ["shape", "circuit"])
def test_make_likelihood_without_viewport_says_so(kind: str) -> None:
    prog = make_program({"A": lambda ctx: [("F", 1.0)]})
    assert prog.viewport is None
    target = Target(np.ones((8, 8), dtype=bool), (0.0, 0.0, 1.0, 0.0))
    with pytest.raises(
        NgpmError,
        match="has no viewport.*add a 'viewport: XMIN XMAX YMIN YMAX' "
        r"line \(`ngpmc check GRAMMAR` proposes one",
    ):
        make_likelihood(kind, prog, target)


def test_a_circuit_run_starts_at_the_bottom_middle_and_scores_equation_2() -> None:
    """Without a target a circuit run grows into grow.circuit_target (50 x 50, bottom middle,
    heading up); with one, the image gives only the start and size: the guide's features
    never hold it, so a run from the same start is the same with any picture."""
    from ngpm_runtime import bundled
    from ngpm_runtime.grow import CIRCUIT_START, circuit_target, grow
    from ngpm_runtime.inference.likelihood import circuit_score
    from ngpm_runtime.inference.smc import TraceRecording

    program = bundled.bundled_program()
    guide = bundled.bundled_guide(program)  # any guide reading target windows
    res = grow(program, None, guide, 3, 1, "circuit", trace=TraceRecording.FULL)
    assert res.image.shape == (50, 50)
    assert res.similarity == circuit_score(res.image) and res.similarity > 0
    x0, y0 = res.primitives[0][1:3]
    assert (x0, y0) == (0.0, pytest.approx(-22 + 0.05 * 24))  # the viewport is -12 12 -22 2
    blank = circuit_target()
    assert blank.start == CIRCUIT_START and not blank.mask.any()
    full = Target(np.ones((50, 50), dtype=bool), CIRCUIT_START, "full")
    again = grow(program, full, guide, 3, 1, "circuit", trace=TraceRecording.FULL)
    assert again.primitives == res.primitives
    pairs = zip(res.smc.best.trace, again.smc.best.trace, strict=True)
    assert all(np.array_equal(a[1], b[1]) for a, b in pairs)  # the same feature rows
