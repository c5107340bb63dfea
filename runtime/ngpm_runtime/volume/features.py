"""Guide features of 3D grammars per site visit (docs/3d.md, "Growing into a volume").

Row layout: `local` = [x, y, z (the voxel grid -> [-1, 1]), H (3), L (3), U (3), width,
depth / derivation_length] + module parameters (site.arity) + prior arguments
(site.n_args()); then `target` and `partial`: at each pyramid level (the grid, then 2x2x2,
4x4x4 and 8x8x8 block means, floor sizes) the cells of a window around the turtle's voxel
(offsets `WINDOWS[window]`, x slowest, z fastest), -1 outside the grid, 0 for a missing
target. The turtle's voxel at a level of size (sx, sy, sz) is floor(u * s) per axis, with u
its position in the grid scaled to [0, 1].

Windows: "cube", the 3x3x3 cells (27 per level, 2 x 27 x 4 = 216 columns) on the grid's
axes; "frame" (the default), 3x3x3 cells that turn with the turtle: the cell holding the
point a H + b L + c U cells of the level from the turtle, for a, b, c in -1, 0, 1 (so
"the target lies to my left" is one column whatever the turtle's heading); and "cross", the
cell and its 6 face neighbours (7 per level, 56 columns), which costs about a quarter of
the window work and of the network's first layer (`python benchmarks/smc3d.py
--features`). A guide's layouts name a frame window by an empty `frame` group (a guide
without it reads "cube" windows, as every guide before "frame" did).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ngpm_runtime.errors import GuideError, TargetError
from ngpm_runtime.program import Program, Site
from ngpm_runtime.volume.raster import N_LEVELS, VoxelCanvas, VoxelGrid, volume_pyramid

N_LOCAL_BASE = 14
DEPTH_COLUMN = 13
_CUBE = np.array(
    [(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)], dtype=np.int64
)
_CROSS = np.array(
    [(-1, 0, 0), (0, -1, 0), (0, 0, -1), (0, 0, 0), (0, 0, 1), (0, 1, 0), (1, 0, 0)],
    dtype=np.int64,
)
WINDOWS = {"cube": _CUBE, "cross": _CROSS, "frame": _CUBE}
FRAME_WINDOWS = ("frame",)  # windows that turn with the turtle (offsets along H, L, U)
DEFAULT_WINDOW = "frame"  # what new traces record; a guide's layouts name its own
OLD_WINDOW = "cube"  # a guide whose layouts name no window reads these (made before "frame")
_NO_TARGET = np.zeros(0, dtype=np.float32)
_NO_VOXELS = np.zeros((0, 1, 1, 1), dtype=np.uint8)
_NO_COUNTS = np.zeros((0, 0), dtype=np.uint16)


def _fit_columns(a: np.ndarray, n: int, k: int) -> np.ndarray:
    """(n, k) float64: `a` reshaped, truncated or zero-padded to k columns."""
    a = np.asarray(a, dtype=np.float64)
    if a.size == 0:
        return np.zeros((n, k))
    a = a.reshape(n, -1)
    if a.shape[1] == k:
        return a
    out = np.zeros((n, k))
    m = min(k, a.shape[1])
    out[:, :m] = a[:, :m]
    return out


class FeatureMaker3D:
    """Builds the float32 feature rows of a 3D grammar's site visits (the interface of
    image/features.FeatureMaker that smc() uses: rows_from, n_features, layout)."""

    context = False  # no context group in 3D
    n_turtle = 13  # the turtle's numbers a row reads: position, H, L, U, width

    def __init__(
        self,
        program: Program,
        grid: VoxelGrid,
        target: Any | None = None,
        window: str = DEFAULT_WINDOW,
    ) -> None:
        if window not in WINDOWS:
            raise ValueError(f"unknown window {window!r}; choose {' or '.join(WINDOWS)}")
        self.program, self.grid, self.window = program, grid, window
        self.offs = WINDOWS[window]
        self.n_window = len(self.offs) * N_LEVELS
        self.n_common = N_LOCAL_BASE + 2 * self.n_window
        self.derivation_length = float(getattr(program, "derivation_length", 1) or 1)
        self.sizes = np.array(
            [[int(s) >> lv for s in grid.shape] for lv in range(N_LEVELS)], dtype=np.int64
        )
        self._geom = np.array([*grid.lo, *grid.extent(), self.derivation_length])
        self.target_flat = _NO_TARGET
        self.tstart = np.zeros(N_LEVELS, dtype=np.int64)
        if target is not None:
            occ = np.asarray(target.occupancy, dtype=bool)
            if VoxelGrid.of_target(target) != grid:
                raise TargetError(f"3D target {target.name!r} does not lie on the run's grid")
            levels = volume_pyramid(occ)
            self.tstart[1:] = np.cumsum([lev.size for lev in levels[:-1]])
            self.target_flat = np.concatenate([lev.reshape(-1) for lev in levels])
        self._rows: dict[int, Any] = {}
        self._block = np.empty((0, self.n_common), dtype=np.float32)
        from ngpm_runtime.volume import kernels

        self._k = kernels

    @staticmethod
    def n_local(site: Site) -> int:
        return N_LOCAL_BASE + int(site.arity) + int(site.n_args())

    def layout(self, site: Site) -> dict[str, slice]:
        """Column ranges of the feature groups for a site."""
        return layout3d(site, self.window)

    def n_features(self, site: Site) -> int:
        return self.n_local(site) + self.n_common - N_LOCAL_BASE

    def forget(self) -> None:
        """Drop the remembered rows (SMC calls it at the start of every step)."""
        self._rows.clear()

    def features(
        self,
        site: Site,
        canvas: VoxelCanvas | None,
        idx: np.ndarray,
        turtles: list[Any],
        depth: np.ndarray,
        params: np.ndarray,
        prior_args: np.ndarray,
    ) -> np.ndarray:
        """Feature rows `(n, n_features(site))` float32 of n particles at one site; turtles:
        their 3D turtle tuples (or rows of at least 13 numbers)."""
        idx = np.asarray(idx, dtype=np.intp).reshape(-1)
        common = self._common(canvas, idx, _turtle_rows(turtles), np.asarray(depth, float))
        return self._site_rows([site], common, [params], [prior_args])[0]

    def features_round(
        self,
        sites: list[Site],
        canvas: VoxelCanvas | None,
        idx: list[int],
        turtles: list[Any],
        depths: list[float],
        params: list[np.ndarray],
        prior_args: list[np.ndarray],
    ) -> list[np.ndarray]:
        """Rows for several sites at once (particles of `sites[j]` one after the other), as
        image/features.FeatureMaker.features_round (the canvases may have changed since
        the last call: nothing remembered is used)."""
        self.forget()
        return self.features_cached(sites, canvas, idx, turtles, depths, params, prior_args)

    def features_cached(
        self,
        sites: list[Site],
        canvas: VoxelCanvas | None,
        idx: list[int],
        turtles: list[Any],
        depths: list[float],
        params: list[np.ndarray],
        prior_args: list[np.ndarray],
    ) -> list[np.ndarray]:
        """Rows for several sites at once (particles of `sites[j]` one after the other),
        the site-independent columns remembered per particle until `forget`, as
        FeatureMaker.features_cached."""
        known = self._rows
        miss = [j for j, (i, t) in enumerate(zip(idx, turtles, strict=True)) if known.get(i) != t]
        ia = np.array(idx, dtype=np.intp)
        top = max(idx) + 1
        if self._block.shape[0] < top:
            grown = np.empty((max(top, 2 * self._block.shape[0]), self.n_common), np.float32)
            grown[: self._block.shape[0]] = self._block
            self._block = grown
        if miss:
            sel = ia[miss]
            rows = _turtle_rows([turtles[j] for j in miss])
            self._block[sel] = self._common(canvas, sel, rows, np.zeros(len(miss)))
            for j in miss:
                known[idx[j]] = turtles[j]
        common = self._block[ia]
        common[:, DEPTH_COLUMN] = np.array(depths, dtype=np.float64) / self.derivation_length
        return self._site_rows(sites, common, params, prior_args)

    def _common(
        self,
        canvas: VoxelCanvas | None,
        idx: np.ndarray,
        turtle: np.ndarray,
        depth: np.ndarray,
        extra: np.ndarray | None = None,
        n_extra: np.ndarray | None = None,
    ) -> np.ndarray:
        """(n, n_common + extra's columns) float32: turtle columns, depth, extra[k,
        :n_extra[k]] and the windows (none: the site-independent columns), one kernel
        call."""
        n = len(idx)
        if extra is None or n_extra is None:
            extra, n_extra = np.zeros((n, 0)), np.zeros(n, dtype=np.int64)
        out = np.empty((n, self.n_common + extra.shape[1]), dtype=np.float32)
        if canvas is not None and canvas.grid != self.grid:
            raise TargetError(f"voxel canvas {canvas.grid} is not the features' {self.grid}")
        vox = _NO_VOXELS if canvas is None else canvas.voxels
        counts = _NO_COUNTS if canvas is None else canvas.counts
        if canvas is not None and not canvas.pyramid:
            raise ValueError("features need a voxel canvas with its pyramid")
        starts = np.zeros(N_LEVELS, dtype=np.int64) if canvas is None else canvas.starts
        self._k.volume_features(
            out,
            turtle,
            np.ascontiguousarray(depth, dtype=np.float64).reshape(-1),
            idx,
            self._geom,
            self.sizes,
            self.offs,
            self.window in FRAME_WINDOWS,
            self.tstart,
            self.target_flat,
            vox,
            counts,
            starts,
            np.ascontiguousarray(extra, dtype=np.float64),
            np.ascontiguousarray(n_extra, dtype=np.int64),
        )
        return out

    def rows_from(
        self,
        canvas: VoxelCanvas | None,
        idx: np.ndarray,
        turtle: np.ndarray,
        depth: np.ndarray,
        extra: np.ndarray,
        n_extra: np.ndarray,
    ) -> np.ndarray:
        """The rows (n, n_common + extra's columns) float32 of particles idx with turtles
        (n, 13) and depths (n,): the local base columns, extra[k, :n_extra[k]] (module
        parameters and prior arguments, fitted to the site), then the windows (as 2D
        FeatureMaker.rows_from; SMC's rounds call it)."""
        return self._common(canvas, idx, turtle, depth, extra, n_extra)

    def _site_rows(
        self,
        sites: list[Site],
        common: np.ndarray,
        params: list[np.ndarray],
        prior_args: list[np.ndarray],
    ) -> list[np.ndarray]:
        """Each site's rows: the local base columns, its module parameters and prior
        arguments, then the windows."""
        out = []
        pos = 0
        for site, par, args in zip(sites, params, prior_args, strict=True):
            m = len(args)
            block = common[pos : pos + m]
            out.append(
                np.concatenate(
                    (
                        block[:, :N_LOCAL_BASE],
                        _fit_columns(par, m, int(site.arity)),
                        _fit_columns(args, m, int(site.n_args())),
                        block[:, N_LOCAL_BASE:],
                    ),
                    axis=1,
                    dtype=np.float32,
                )
            )
            pos += m
        if pos != len(common):
            raise ValueError(f"features: {len(common)} particles, {pos} rows of arguments")
        return out


def layout3d(site: Site, window: str = DEFAULT_WINDOW) -> dict[str, slice]:
    """Column ranges of a site's feature groups (local, target, partial) with `window`; a
    window that turns with the turtle adds the empty group `frame` (its mark)."""
    nl = FeatureMaker3D.n_local(site)
    nw = len(WINDOWS[window]) * N_LEVELS
    out = {
        "local": slice(0, nl),
        "target": slice(nl, nl + nw),
        "partial": slice(nl + nw, nl + 2 * nw),
    }
    if window in FRAME_WINDOWS:
        out["frame"] = slice(nl + 2 * nw, nl + 2 * nw)
    return out


def window_of(layouts: Any) -> str:
    """The window stored layouts ({site: {group: range}}) were made with: "frame" when they
    carry its mark, else the windows every guide read before it (OLD_WINDOW)."""
    marked = [isinstance(lay, dict) and "frame" in lay for lay in dict(layouts).values()]
    return "frame" if any(marked) else OLD_WINDOW


def check_guide_layouts(path: str, meta: dict[str, Any], program: Program) -> None:
    """GuideError unless a guide's stored feature layouts are the ones a 3D run computes
    (with the window they name; 3D rows have no context or far group)."""
    features = meta["features"]
    if "context" in str(features["feature_set"]).split("+"):
        raise GuideError(
            f"{path}: feature set {features['feature_set']} reads 2D context features; "
            f"{program.name} is a 3D grammar (train it with --features all)"
        )
    stored = features["layouts"]
    window = window_of(stored)
    for site in program.sites:
        lay = stored.get(str(site.index))
        if lay is None:
            continue
        ours = {g: [sl.start, sl.stop] for g, sl in layout3d(site, window).items()}
        theirs = {g: [int(v) for v in lay[g]] for g in lay if g not in ("context", "far")}
        if theirs != ours:
            raise GuideError(
                f"{path}: site {site.index}'s feature layout {theirs} is not the 3D "
                f"features' {ours} (a 2D guide, or trained with other 3D features)"
            )


def _turtle_rows(turtles: list[Any]) -> np.ndarray:
    """(n, 13) float64: position, H, L, U and width of 3D turtle tuples."""
    return np.array([t[:13] for t in turtles], dtype=np.float64).reshape(len(turtles), 13)
