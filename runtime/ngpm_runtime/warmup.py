"""The compiled kernels' disk cache: is it there, and filling it ahead of the first run.

numba compiles the kernels (ngpm_runtime/kernels.py and the modules it names) the first
time a process uses them on a machine, about 15-30 s, and caches the machine code on disk
(`__pycache__` beside the module, or numba's user cache when that folder is not writable,
or `$NUMBA_CACHE_DIR`). Later processes load it in well under a second.

`cache_is_cold()` tells whether a kernel has no cache file yet (the CLI prints a one-line
note then). `warm_up()` fills the cache by running tiny SMC runs of
the bundled vines model through every kernel path (unguided, guided, circuit, full
traces, the vines grammar's compiled deriver: geometry/compiled.py, whose modules live in
its own cache folder); `python -m ngpm_runtime.warmup` runs it, e.g. right after `pip
install` or in a Docker build.
"""

from __future__ import annotations

import os
import sys
import time
from importlib import import_module
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # imported on use: this module is imported without numpy's cost
    from ngpm_runtime.image.targets import Target
    from ngpm_runtime.inference.guide import Guide
    from ngpm_runtime.program import Program
    from ngpm_runtime.volume.target import VolumeTarget

# modules (relative to the package) whose @njit(cache=True) kernels are cached
KERNEL_MODULES = ("kernels", "round_kernels", "volume.kernels")


def cache_is_cold() -> bool:
    """True when a kernel has no cache index file where numba will look for it (imports
    numba: ask only where kernels are about to run). False when numba's cache layout is
    not the one known here (its private `_cache` attributes)."""
    from numba.core.dispatcher import Dispatcher

    for name in KERNEL_MODULES:
        module = import_module(f"ngpm_runtime.{name}")
        for attr, value in vars(module).items():
            if attr.startswith("_") or not isinstance(value, Dispatcher):
                continue
            try:
                index = getattr(value, "_cache")._cache_file._index_path  # noqa: B009
            except AttributeError:
                return False
            if not os.path.exists(index):
                return True
    return False


COLD_NOTE = (
    "compiling the SMC kernels for this machine (once, about 30 s; later runs load them "
    "from disk; `python -m ngpm_runtime.warmup` does it ahead of time)"
)


def warm_up() -> float:
    """Run every kernel path once on tiny inputs (compiling and caching what is missing);
    returns the seconds it took."""
    from ngpm_runtime.bundled import bundled_program, default_guide, demo_targets
    from ngpm_runtime.grow import grow
    from ngpm_runtime.inference import smc
    from ngpm_runtime.inference.smc import TraceRecording

    t0 = time.perf_counter()
    program = bundled_program()
    target = demo_targets()[0]
    guide = default_guide(program)
    compiled = smc.USE_COMPILED
    try:
        for smc.USE_COMPILED in (False, True):  # the Python deriver's kernels, the compiled's
            _warm_2d(program, target, guide)
    finally:
        smc.USE_COMPILED = compiled
    program3d, block, guide3d = _tiny_3d()
    grow(program3d, block, guide3d, n_particles=2, seed=0, max_modules=40)  # 3D kernels
    grow(program3d, block, None, n_particles=2, seed=0, trace=TraceRecording.FULL, max_modules=40)
    return time.perf_counter() - t0


def _warm_2d(program: Program, target: Target, guide: Guide | None) -> None:
    """Tiny 2D runs down every path: unguided (COMPILE_FROM particles first: the vines
    deriver is compiled then, where the compiled deriver is on), guided, feature traces
    and their replay, circuits."""
    from ngpm_runtime.grow import grow
    from ngpm_runtime.inference.smc import COMPILE_FROM, TraceRecording, replay

    grow(program, target, None, n_particles=COMPILE_FROM, seed=0, trace=TraceRecording.VALUES)
    grow(program, target, None, n_particles=2, seed=0, max_modules=40)
    grow(program, target, guide, n_particles=2, seed=0, max_modules=40)
    full = grow(program, target, None, 2, 0, trace=TraceRecording.FULL, max_modules=40).smc
    assert program.viewport is not None  # the bundled vines have one
    start = target.start_pose(program.viewport)
    values = [(s, v) for s, _, v in full.best.trace or []]
    replay(program, values, start, target.size, target.mask, max_modules=40)
    grow(program, None, None, n_particles=2, seed=0, likelihood="circuit", max_modules=40)


def _tiny_3d() -> tuple[Program, VolumeTarget, Guide]:
    """(program, target, guide): the bundled 3D plant, a 16^3 block in its box, its guide."""
    import numpy as np

    from ngpm_runtime.bundled import bundled_guide3d, bundled_program3d
    from ngpm_runtime.volume.target import VolumeTarget, box_grid

    program = bundled_program3d()
    assert program.box is not None  # a 3D grammar has its box
    lo, voxel = box_grid(program.box, 16)
    occupancy = np.zeros((16, 16, 16), dtype=bool)
    occupancy[4:12, :10, 4:12] = True
    start = lo + np.array([8.0, 0.0, 8.0]) * voxel
    return program, VolumeTarget(occupancy, lo, voxel, start, "block"), bundled_guide3d(program)


def main() -> int:
    cold = cache_is_cold()
    print("ngpm: " + (COLD_NOTE if cold else "loading the cached SMC kernels"), file=sys.stderr)
    seconds = warm_up()
    print(f"ngpm: kernels ready ({seconds:.1f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
