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
