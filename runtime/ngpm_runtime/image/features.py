"""Guide features per site visit (architecture.md section 6), vectorized over particles.

Row layout: `local` = [x, y (viewport -> [-1, 1]), heading mod 360 -> [-1, 1], sin, cos,
width, depth / derivation_length] + module parameters (site.arity) + prior arguments
(site.n_args()); then `target` (36) and `partial` (36): at each pyramid level (H, H/2, H/4,
H/8) the 3x3 cells around the turtle's pixel (row-major, top row first), -1 outside the image.
The turtle's pixel at a level of size (h, w) is (floor(v * h), floor(u * w)) with (u, v) its
normalized image position (u right, v down from ymax).

With `context=True` (issue #11's feature experiment) a `context` group (17) follows: the
target's unfilled and overdrawn fractions (sum of max(t - c, 0) and of max(c - t, 0) over
sum t, pyramid level 2), then "look-ahead" samples of the unfilled target max(t - c, 0) at
level 1 (H/2), -1 outside the image, at the points `RAY_DIST` x viewport width away from the
turtle in the directions heading + `RAY_ANGLES` degrees (angle-major). Unlike the windows,
which lie on image axes, these turn with the turtle.

With `far=True` (which implies the context) a `far` group (10) follows it: the same
look-ahead at `FAR_DIST` x viewport width, on level 3 (H/8, whose cells average 8 x 8
pixels), so a choice made where nothing is drawn yet (the first fork of a plant that
derives top-down) sees how far and which way the target reaches.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ngpm_runtime.errors import TargetError
from ngpm_runtime.image.raster import (
    N_LEVELS,
    PAD,
    Canvas,
    Viewport,
    as_viewport,
    padded_layout,
    padded_pyramid,
    pyramid,
)
from ngpm_runtime.program import Program, Site

# _context_geometry's answer (its docstring names the parts)
ContextGeometry = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]

N_LOCAL_BASE = 7
N_WINDOW = 9 * N_LEVELS  # 36 per image
RAY_ANGLES = (-45.0, -22.5, 0.0, 22.5, 45.0)  # look-ahead directions, degrees from heading
RAY_DIST = (1 / 12, 1 / 6, 1 / 3)  # look-ahead distances, fractions of the viewport width
FAR_DIST = (2 / 3, 1.0)  # the far look-ahead's distances
N_CONTEXT = 2 + len(RAY_ANGLES) * len(RAY_DIST)
N_FAR = len(RAY_ANGLES) * len(FAR_DIST)
_RAY_LEVEL, _FAR_LEVEL, _FILL_LEVEL = 1, 3, 2
# the feature sets a guide network may read: the column groups of `FeatureMaker.layout` it
# selects (ngpm_compiler/learning/nets.py trains them; inference/guide.py checks a file's)
FEATURE_GROUPS = {
    "const": (),
    "local": ("local",),
    "local+target": ("local", "target"),
    "all": ("local", "target", "partial"),
    "all+context": ("local", "target", "partial", "context"),  # issue #11's experiment
    "all+context+far": ("local", "target", "partial", "context", "far"),
}
FEATURE_SETS = tuple(FEATURE_GROUPS)
_DR = np.repeat(np.arange(-1, 2), 3)  # 3x3 window offsets, row-major
_DC = np.tile(np.arange(-1, 2), 3)
# what the feature kernel gets for a group that is not there
_NO_TARGET = np.zeros(0, dtype=np.float32)
_NO_CANVAS = np.zeros((0, 0), dtype=np.float32)
_NO_SIZE = np.zeros((3, 0))
_NO_OFFS = np.zeros((0, 9), dtype=np.intp)
_NO_CTX = np.zeros((0, 6))
_NO_GEOM = np.zeros(2)
_NO_CELLS = np.zeros(0, dtype=np.intp)


def last_group(feature_set: str) -> str:
    """The group a network of `feature_set` reads its rows up to: the runtime computes the
    context and far columns only for networks that read them, so their rows end there."""
    groups = FEATURE_GROUPS[feature_set]
    return next((g for g in ("far", "context") if g in groups), "partial")


def _fit_columns(a: np.ndarray, n: int, k: int) -> np.ndarray:
    """(n, k) float64: `a` reshaped, truncated or zero-padded to k columns."""
    if type(a) is np.ndarray and a.shape == (n, k):
        return a
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


def _extra_columns(
    sites: list[Site], params: list[np.ndarray], prior_args: list[np.ndarray], n: int
) -> tuple[np.ndarray, np.ndarray]:
    """Each row's module parameters and prior arguments (fitted to the site's arity and
    argument count) as (n, widest) float64, and each row's width."""
    blocks = []
    widths = []
    for site, par, args in zip(sites, params, prior_args, strict=True):
        m = len(args)
        a, k = int(site.arity), int(site.n_args())
        blocks.append(
            np.concatenate((_fit_columns(par, m, a), _fit_columns(args, m, k)), axis=1)
            if a
            else _fit_columns(args, m, k)
        )
        widths.append(a + k)
    counts = [len(b) for b in blocks]
    if sum(counts) != n:
        raise ValueError(f"features: {n} particles, {sum(counts)} rows of arguments")
    if len(blocks) == 1:
        b = blocks[0]
        if not (b.flags.c_contiguous and b.flags.writeable):  # one compiled signature
            b = b.copy()
        return b, np.full(n, widths[0], dtype=np.int64)
    extra = np.zeros((n, max(widths)))
    pos = 0
    for b, w in zip(blocks, widths, strict=True):
        extra[pos : pos + len(b), :w] = b
        pos += len(b)
    return extra, np.repeat(np.array(widths, dtype=np.int64), counts)


class FeatureMaker:
    """Builds the float32 feature rows the guide networks read."""

    n_turtle = 4  # the turtle's numbers a row reads: x, y, heading, width

    def __init__(
        self,
        program: Program,
        viewport: Viewport,
        target_mask: np.ndarray | None,
        context: bool = False,
        far: bool = False,
    ) -> None:
        self.program = program
        self.far = bool(far)
        self.context = bool(context) or self.far
        self.n_common = (
            N_LOCAL_BASE + 2 * N_WINDOW + (N_CONTEXT if self.context else 0) + N_FAR * self.far
        )
        self.viewport = as_viewport(viewport)
        self.derivation_length = float(getattr(program, "derivation_length", 1) or 1)
        self.target_levels = (
            None if target_mask is None else pyramid(np.asarray(target_mask, dtype=bool))
        )
        self._target_flat: np.ndarray | None = None
        self._geom: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._context_geom: dict[tuple[int, int], ContextGeometry] = {}
        xmin, xmax, ymin, ymax = self.viewport
        self._span = np.array([xmax - xmin, -(ymax - ymin)])  # (y - ymax) / -(...) = v
        # the feature kernel's (origin x, origin y, span x, span y, derivation length, fill
        # of absent target windows, of absent canvas windows), by (target?, canvas?) when
        # there is no image (windows -1 where the group exists), else [False, False]
        self._view_fill = {
            (t, c): np.array([xmin, ymax, *self._span, self.derivation_length, -1.0 * t, -1.0 * c])
            for t in (False, True)
            for c in (False, True)
        }
        # kernels.feature_windows' arguments for the last canvas (_kernel_args)
        self._canvas: Canvas | None = None
        self._args: tuple[np.ndarray, ...] | None = None
        from ngpm_runtime import kernels  # numba loads when features are made

        self._k = kernels

    def _shape(self, canvas: Canvas | None) -> tuple[int, int]:
        if canvas is not None:
            if (
                self.target_levels is not None
                and self.target_levels[0].shape != canvas.image.shape[1:]
            ):
                raise TargetError(
                    f"canvas {canvas.image.shape[1:]} and target "
                    f"{self.target_levels[0].shape} differ in size"
                )
            return canvas.height, canvas.width
        if self.target_levels is not None:
            return self.target_levels[0].shape
        return (0, 0)

    @staticmethod
    def n_local(site: Site) -> int:
        return N_LOCAL_BASE + int(site.arity) + int(site.n_args())

    def layout(self, site: Site) -> dict[str, slice]:
        """Column ranges of the feature groups for a site."""
        nl = self.n_local(site)
        out = {
            "local": slice(0, nl),
            "target": slice(nl, nl + N_WINDOW),
            "partial": slice(nl + N_WINDOW, nl + 2 * N_WINDOW),
        }
        if self.context:
            out["context"] = slice(nl + 2 * N_WINDOW, nl + 2 * N_WINDOW + N_CONTEXT)
        if self.far:
            end = nl + 2 * N_WINDOW + N_CONTEXT
            out["far"] = slice(end, end + N_FAR)
        return out

    def n_features(self, site: Site) -> int:
        return self.n_local(site) + self.n_common - N_LOCAL_BASE

    def _windows(self, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
        """Per canvas size, in raster's padded pyramid layout: (3, L) level heights, widths
        and padded widths (float64), and the 3x3 window offsets per level (L, 9) from a
        padded row-major index, each level's start and padding folded in."""
        key = (h, w)
        if key not in self._geom:
            hp, wp, starts = padded_layout(h, w)
            size = np.array(
                [[h >> lv for lv in range(N_LEVELS)], [w >> lv for lv in range(N_LEVELS)], wp],
                dtype=np.float64,
            )
            offs = _DR[None, :] * wp[:, None] + _DC[None, :] + (starts + PAD * wp + PAD)[:, None]
            self._geom[key] = (size, np.ascontiguousarray(offs, dtype=np.intp))
        return self._geom[key]

    def _padded_target(self) -> np.ndarray:
        """The target pyramid in raster's padded layout, -1 in the padding (float32)."""
        if self._target_flat is None:
            self._target_flat = padded_pyramid(list(self.target_levels or []))
        return self._target_flat

    def features(
        self,
        site: Site,
        canvas: Canvas | None,
        idx: np.ndarray,
        turtle: np.ndarray,
        depth: np.ndarray,
        params: np.ndarray,
        prior_args: np.ndarray,
    ) -> np.ndarray:
        """Feature rows `(n, n_features(site))` float32 of n particles at one site."""
        idx = np.asarray(idx, dtype=np.intp).reshape(-1)
        return self.features_round([site], canvas, idx, turtle, depth, [params], [prior_args])[0]

    def features_round(
        self,
        sites: list[Site],
        canvas: Canvas | None,
        idx: np.ndarray | Sequence[int],
        turtle: np.ndarray | Sequence[Sequence[float]],
        depth: np.ndarray | Sequence[float],
        params: list[np.ndarray],
        prior_args: list[np.ndarray],
    ) -> list[np.ndarray]:
        """Feature rows for several sites at once: `idx`, `turtle` (n, 4) and `depth` (n,)
        list the particles of every site one after the other (`len(params[j])` of them at
        `sites[j]`); returns one array per site (views of `rows`' answer). Each row is the
        one `features` gives alone."""
        rows = self.rows(sites, canvas, idx, turtle, depth, params, prior_args)
        if len(sites) == 1:
            return [rows]
        out = []
        pos = 0
        for site, args in zip(sites, prior_args, strict=True):
            m = len(args)
            out.append(rows[pos : pos + m, : self.n_features(site)])
            pos += m
        return out

    def rows(
        self,
        sites: list[Site],
        canvas: Canvas | None,
        idx: np.ndarray | Sequence[int],
        turtle: np.ndarray | Sequence[Sequence[float]],
        depth: np.ndarray | Sequence[float],
        params: list[np.ndarray],
        prior_args: list[np.ndarray],
    ) -> np.ndarray:
        """`features_round`'s rows in one float32 array (n, widest row): row k of a site
        with w = n_features(site) columns is rows[k, :w] (one kernel call)."""
        idx = np.asarray(idx, dtype=np.intp).reshape(-1)
        n = len(idx)
        extra, n_extra = _extra_columns(sites, params, prior_args, n)
        return self.rows_from(
            canvas,
            idx,
            np.ascontiguousarray(turtle, dtype=np.float64).reshape(n, 4),
            np.ascontiguousarray(depth, dtype=np.float64).reshape(n),
            extra,
            n_extra,
        )

    def _common(
        self, canvas: Canvas | None, idx: np.ndarray, turtle: np.ndarray, depth: np.ndarray
    ) -> np.ndarray:
        """(n, 7 + 72 [+ 17 [+ 10]]) float32: the site-independent columns (turtle state,
        depth, target and partial windows, context, far) of every particle."""
        n = len(idx)
        return self.rows_from(canvas, idx, turtle, depth, np.zeros((n, 0)), np.zeros(n, np.int64))

    def rows_from(
        self,
        canvas: Canvas | None,
        idx: np.ndarray,
        turtle: np.ndarray,
        depth: np.ndarray,
        extra: np.ndarray,
        n_extra: np.ndarray,
    ) -> np.ndarray:
        """The rows (n, n_common + extra's columns) of particles idx (intp) with turtles
        (n, 4) and depths (n,) (float64): turtle columns, extra[k, :n_extra[k]] (module
        parameters and prior arguments, fitted to the site), windows and context, by
        kernels.feature_windows. SMC's rounds call it (their rows unpacked by
        kernels.unpack_round)."""
        out = np.empty((len(idx), self.n_common + extra.shape[1]), dtype=np.float32)
        view, size, offs, target, rows, rays, geom, cells, t = self.window_args(canvas)
        self._k.feature_windows(
            out,
            turtle,
            depth,
            idx,
            view,
            size,
            offs,
            target,
            rows,
            rays,
            geom,
            cells,
            t,
            extra,
            n_extra,
            self._k.NO_MEMO,
            self._k.NO_MEMO_KEY,
        )
        return out

    def window_args(self, canvas: Canvas | None) -> tuple[np.ndarray, ...]:
        """kernels.feature_windows' arguments past the rows and the particles' state, in
        its order: view, level sizes, window offsets, target pyramid, the canvas rows and
        the context's geometry (kernels.serve_round takes them as one tuple)."""
        if canvas is not self._canvas or self._args is None:  # checked once per canvas
            self._args = self._kernel_args(canvas)
            self._canvas = canvas
        view, size, offs, target, rays, geom, cells, t = self._args
        rows = _NO_CANVAS if canvas is None or not size.shape[1] else canvas.padded
        return (view, size, offs, target, rows, rays, geom, cells, t)

    def _kernel_args(self, canvas: Canvas | None) -> tuple[np.ndarray, ...]:
        """kernels.feature_windows' arguments for `canvas` (TargetError if its size is not
        the target's) but the rows, the particles' state and the canvas rows: view, level
        sizes, window offsets, target pyramid and the context's geometry."""
        h, w = self._shape(canvas)
        if h == 0 or w == 0:  # no image: the turtle columns, windows all 0 or -1
            view = self._view_fill[self.target_levels is not None, canvas is not None]
            return (view, _NO_SIZE, _NO_OFFS, _NO_TARGET, _NO_CTX, _NO_GEOM, _NO_CELLS, _NO_TARGET)
        size, offs = self._windows(h, w)
        target_flat = _NO_TARGET if self.target_levels is None else self._padded_target()
        if self.context and self.target_levels is not None and canvas is not None:
            cells, t, rays, geom = self._context_geometry(h, w)
        else:
            cells, t, rays, geom = _NO_CELLS, _NO_TARGET, _NO_CTX, _NO_GEOM
        return (self._view_fill[False, False], size, offs, target_flat, rays, geom, cells, t)

    def _context_geometry(self, h: int, w: int) -> ContextGeometry:
        """Per canvas size: the fill level's cells in the padded row, the target there, the
        look-ahead rows (15, or 25 with the far group; 6): angle, distance, their level's
        first cell (start + padding), padded width, height and width; and the kernel's
        `ctx_geom`: the target's sum there and the viewport's aspect."""
        key = (h, w)
        if key not in self._context_geom:
            _, wp, starts = padded_layout(h, w)
            lv = _FILL_LEVEL
            cells = (
                starts[lv]
                + (np.arange(h >> lv)[:, None] + PAD) * wp[lv]
                + np.arange(w >> lv)[None, :]
                + PAD
            ).reshape(-1)
            t = self._padded_target()[cells]
            groups = [(RAY_DIST, _RAY_LEVEL)] + [(FAR_DIST, _FAR_LEVEL)] * self.far
            rays = np.array(
                [
                    (a, d, int(starts[lv] + PAD * wp[lv] + PAD), wp[lv], h >> lv, w >> lv)
                    for dist, lv in groups
                    for a in RAY_ANGLES  # angle-major
                    for d in dist
                ],
                dtype=np.float64,
            )
            aspect = -self._span[0] / self._span[1]  # viewport width / height
            geom = [max(float(t.sum()), 1e-6), aspect]
            cells = np.ascontiguousarray(cells, dtype=np.intp)
            self._context_geom[key] = (cells, t, rays, np.array(geom, dtype=np.float64))
        return self._context_geom[key]
