"""smc() and grow() with a 3D grammar (volume/run.py): growth into a VolumeTarget made in
the test, seeded reproducibility, the start point, and one-line errors for mixed 2D/3D."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from fixtures.tiny_programs import make_program
from fixtures.volume3d import ball_target
from ngpm_runtime.bundled import bundled_program
from ngpm_runtime.errors import NgpmError, ProgramError
from ngpm_runtime.grow import grow
from ngpm_runtime.inference.smc import SMCOptionError, SMCOptions, TraceRecording, smc
from ngpm_runtime.volume.likelihood import VoxelLikelihood, volume_similarity
from ngpm_runtime.volume.raster import VoxelGrid, voxelize
from repo_paths import REPO


@pytest.fixture(scope="module")
def tree():
    """stochastic_tree3d with 3 derivation steps instead of 6 (a quick test)."""
    from ngpm_compiler.language.compile import compile_grammar

    path = REPO / "grammars" / "stochastic_tree3d.lsys"
    src = path.read_text().replace("derivation length: 6", "derivation length: 3")
    return compile_grammar(src, filename=str(path)).program()


@pytest.fixture(scope="module")
def crown(tree):
    grid = VoxelGrid.of_box(tree.box, 16)
    ball = ball_target(grid, (0.0, 450.0, 0.0), 300.0, name="crown")
    return replace(ball, start=np.zeros(3))  # the trunk starts below the crown


def test_grow_into_a_volume(tree, crown) -> None:
    a = grow(tree, crown, None, 12, seed=3)
    b = grow(tree, crown, None, 12, seed=3)
    assert a.primitives == b.primitives and a.similarity == b.similarity  # seeded
    vox = voxelize(a.primitives, VoxelGrid.of_target(crown))
    np.testing.assert_array_equal(a.image, vox)
    assert a.similarity == volume_similarity(vox, crown.occupancy) and a.similarity > 0
    assert a.smc.best.log_likelihood == pytest.approx(
        VoxelLikelihood(crown, tree.box).full(vox, _box(a.primitives)), rel=1e-9
    )
    # the trunk starts at the target's start point, z included
    moved = crown.__class__(
        crown.occupancy, crown.lo, crown.voxel, np.array([10.0, 0.0, -50.0]), "m"
    )
    first = grow(tree, moved, None, 2, seed=0).primitives[0]
    assert first[0] == "seg3" and first[1:4] == (10.0, 0.0, -50.0)


def test_grow_takes_the_voxel_likelihood_sigma(tree, crown) -> None:
    soft = grow(tree, crown, None, 12, seed=3, sigma=0.05)
    vox = voxelize(soft.primitives, VoxelGrid.of_target(crown))
    full = VoxelLikelihood(crown, tree.box, sigma=0.05).full(vox, _box(soft.primitives))
    assert soft.smc.best.log_likelihood == pytest.approx(full, rel=1e-9)
    sharp = VoxelLikelihood(crown, tree.box).full(vox, _box(soft.primitives))
    assert sharp < full  # the default sigma (0.02) is sharper
    assert (
        grow(tree, crown, None, 12, seed=3, sigma=0.02).primitives
        == grow(tree, crown, None, 12, seed=3).primitives
    )
    with pytest.raises(NgpmError, match="3D grammars"):
        grow(bundled_program(), None, None, 2, sigma=0.05)  # vines: 2D


def _box(prims) -> np.ndarray:
    from ngpm_runtime.geometry.turtle3d import bounds3d

    return np.array(bounds3d(prims), dtype=float)


def test_guided_growth_reads_3d_features(tree, crown) -> None:
    seen: list[int] = []

    class Reader:
        uses_features = True

        def propose(self, site, args, feats, rng):
            from ngpm_runtime.inference.distributions import prior_draw

            seen.append(feats.shape[1])
            return prior_draw(site, args, rng)

    res = grow(tree, crown, Reader(), 4, seed=1, trace=TraceRecording.FULL)
    assert seen and min(seen) >= 14 + 216 and res.smc.best.trace


def test_mixing_2d_and_3d_is_a_one_line_error(tree, crown) -> None:
    flat = make_program({}, axiom=[("F", 1.0)], viewport=(-1, 1, -1, 1))
    with pytest.raises(SMCOptionError, match="2D grammar"):
        smc(flat, None, 2, options=SMCOptions(volume=crown, trace=TraceRecording.FULL))
    with pytest.raises(ProgramError, match="not a target mask"):
        smc(tree, None, 2, options=SMCOptions(target_mask=np.ones((50, 50), bool)))
    other = ball_target(VoxelGrid.of_box(tree.box, 8), (0.0, 450.0, 0.0), 300.0)
    with pytest.raises(ProgramError, match="differ"):
        smc(tree, VoxelLikelihood(crown, tree.box), 2, options=SMCOptions(volume=other))
    with pytest.raises(NgpmError, match="3D target"):
        grow(tree, None)
    with pytest.raises(NgpmError, match="shape likelihood only"):
        grow(tree, crown, likelihood="circuit")
    with pytest.raises(SMCOptionError, match="start must be"):
        smc(flat, None, 1, options=SMCOptions(start=(0.0, 0.0, 0.0, 90.0)))
    for err in (SMCOptionError, ProgramError, NgpmError):
        assert issubclass(err, NgpmError)
