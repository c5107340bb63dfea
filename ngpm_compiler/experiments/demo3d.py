"""The demo's 3D rows (issue #26): the bundled vines3d vine grown into 3D targets it was
not trained on, guided by its bundled guide and unguided at about the same time.

Targets (32^3 voxels, placed in vines3d's box as `ngpmc grow` places them):
`vase`, the mesh file `demo_vase.obj` the project makes (datasets/demo_targets.vase_mesh)
and ships; `glyph_extruded`, the 2D demo's glyph picture pushed into a slab a quarter of its
side deep (`ngpmc grow demo_glyph.png --extrude 0.25`: the vine starts at the picture's 2D
start, the end of the S's stroke, and grows up out of the slab, so no run gets far);
`tree_revolved` and `mushroom_revolved`, targets 7 and 8 of the held-out `revolved` set
(`ngpmc targets build revolved`, seed 0). Guided runs use `particles` particles, unguided
runs `UNGUIDED_FACTOR` times as many, which take about as long (the demo prints both).

Used by experiments/demo.py (`ngpmc demo`), which draws and tabulates these rows.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

RESOLUTION = 32
EXTRUDE = 0.25
REVOLVED = {7: "tree_revolved", 8: "mushroom_revolved"}  # index in the revolved set -> name
# unguided particles per guided particle: unguided N = 60 takes about as long as guided
# N = 10 of the bundled vines3d on these targets (at N = 20: 0.02 s against 0.10 s a run)
UNGUIDED_FACTOR = 6
SOURCES = {
    "vase": "mesh demo_vase.obj",
    "glyph_extruded": f"glyph picture, --extrude {EXTRUDE:g}",
    "tree_revolved": "held-out revolved set, #7",
    "mushroom_revolved": "held-out revolved set, #8",
}


@dataclass
class Demo3DRow:
    """One 3D target and its runs (ngpm_runtime.grow.GrowResult per seed)."""

    target: Any  # ngpm_runtime.volume.target.VolumeTarget
    guided_runs: list[Any]
    unguided_runs: list[Any]

    @property
    def source(self) -> str:
        return SOURCES[self.target.name]


def demo_targets3d(program: Any) -> list[Any]:
    """The demo's 3D targets, in the grid of `program` (a 3D grammar), in SOURCES order."""
    from dataclasses import replace

    from ngpm_runtime.bundled import data_path, demo_target_path
    from ngpm_runtime.volume.load import load_volume_target, place, program_box

    from ngpm_compiler.datasets.demo_targets import VASE_FILE
    from ngpm_compiler.datasets.sets3d import build_revolved

    box = program_box(program)
    vase = load_volume_target(data_path(VASE_FILE), program, resolution=RESOLUTION)
    glyph = load_volume_target(
        demo_target_path("glyph"), program, resolution=RESOLUTION, extrude=EXTRUDE
    )
    out = [replace(vase, name="vase"), replace(glyph, name="glyph_extruded")]
    made = build_revolved(max(REVOLVED) + 1, 0, RESOLUTION)
    for j, (target, _) in enumerate(itertools.islice(made, max(REVOLVED) + 1)):
        if j in REVOLVED:
            out.append(replace(place(target, box, RESOLUTION), name=REVOLVED[j]))
    return out


def run_demo3d(
    particles: int = 10,
    seed: int = 0,
    runs: int = 3,
    program: Any = None,
    guide: Any = None,
) -> list[Demo3DRow]:
    """Guided (`particles`) and unguided (UNGUIDED_FACTOR x `particles`) SMC into every 3D
    target, seeds seed .. seed + runs - 1; program and guide default to the bundled
    vines3d and its guide."""
    from ngpm_runtime.bundled import bundled_guide3d, bundled_program3d
    from ngpm_runtime.grow import grow

    program = bundled_program3d() if program is None else program
    guide = bundled_guide3d(program) if guide is None else guide
    rows = []
    for target in demo_targets3d(program):
        seeds = range(seed, seed + runs)
        guided = [grow(program, target, guide, particles, s) for s in seeds]
        unguided = [grow(program, target, None, UNGUIDED_FACTOR * particles, s) for s in seeds]
        rows.append(Demo3DRow(target, guided, unguided))
    return rows
