"""The numpy feature rows the compiled feature kernel replaced (ngpm_runtime/kernels.py),
kept as the tests' reference: this `FeatureMaker` is the runtime's before numba (git
history: runtime/ngpm_runtime/image/features.py)."""

from __future__ import annotations

import numpy as np
from ngpm_runtime.errors import TargetError
from ngpm_runtime.geometry.turtle import Turtle
from ngpm_runtime.image.features import (
    FAR_DIST,
    FEATURE_GROUPS,
    N_CONTEXT,
    N_FAR,
    N_LOCAL_BASE,
    N_WINDOW,
    RAY_ANGLES,
    RAY_DIST,
)
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
ContextGeometry = tuple[
    np.ndarray, np.ndarray, float, list[tuple[np.ndarray, np.ndarray, int, int, int, int]], float
]

_RAY_LEVEL, _FAR_LEVEL, _FILL_LEVEL = 1, 3, 2
__all__ = ["FEATURE_GROUPS", "FeatureMaker"]
_DR = np.repeat(np.arange(-1, 2), 3)  # 3x3 window offsets, row-major
_DC = np.tile(np.arange(-1, 2), 3)
_TWO_NEG = np.array([2.0, -2.0])
_ONE_POS = np.array([-1.0, 1.0])


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


def _unit(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    # non-finite or far-away positions read as outside everywhere
    u = np.nan_to_num(np.asarray(u, dtype=np.float64), nan=-10.0, posinf=10.0, neginf=-10.0)
    v = np.nan_to_num(np.asarray(v, dtype=np.float64), nan=-10.0, posinf=10.0, neginf=-10.0)
    return np.minimum(np.maximum(u, -10.0), 10.0), np.minimum(np.maximum(v, -10.0), 10.0)


class FeatureMaker:
    """Builds the float32 feature rows the guide networks read."""

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
        self._geom: dict[tuple[int, int], tuple[np.ndarray, ...]] = {}
        self._context_geom: dict[tuple[int, int], ContextGeometry] = {}
        # features_cached: particle -> turtle state of its site-independent row in _block
        self._rows: dict[int, Turtle] = {}
        self._block = np.empty((0, self.n_common), dtype=np.float32)
        xmin, xmax, ymin, ymax = self.viewport
        self._origin = np.array([xmin, ymax])
        self._span = np.array([xmax - xmin, -(ymax - ymin)])  # (y - ymax) / -(...) = v

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

    def _windows(self, h: int, w: int) -> tuple[np.ndarray, ...]:
        """Per canvas size, in raster's padded pyramid layout: (2, L) level (heights,
        widths), lowest and highest (row, col) a window centre is clipped to, the (padded
        width, 1) multipliers of a (row, col), all float64, and the 3x3 window offsets per
        level (L, 9) from a padded row-major index, each level's start and padding folded in.
        """
        key = (h, w)
        if key not in self._geom:
            hp, wp, starts = padded_layout(h, w)
            size = np.array(
                [[h >> lv for lv in range(N_LEVELS)], [w >> lv for lv in range(N_LEVELS)]],
                dtype=np.float64,
            )
            mult = np.stack([wp.astype(np.float64), np.ones(N_LEVELS)])
            offs = _DR[None, :] * wp[:, None] + _DC[None, :] + (starts + PAD * wp + PAD)[:, None]
            self._geom[key] = (size, np.full_like(size, -2.0), size + 1, mult, offs.astype(np.intp))
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
        idx: np.ndarray,
        turtle: np.ndarray,
        depth: np.ndarray,
        params: list[np.ndarray],
        prior_args: list[np.ndarray],
    ) -> list[np.ndarray]:
        """Feature rows for several sites at once: `idx`, `turtle` (n, 4) and `depth` (n,)
        list the particles of every site one after the other (`len(params[j])` of them at
        `sites[j]`); returns one array per site. The turtle and window columns are computed
        for all n rows in one pass; each row is the one `features` gives alone."""
        idx = np.asarray(idx, dtype=np.intp).reshape(-1)
        n = len(idx)
        common = self._common(
            canvas,
            idx,
            np.asarray(turtle, dtype=np.float64).reshape(n, 4),
            np.asarray(depth, dtype=np.float64).reshape(n),
        )
        return self._site_rows(sites, common, params, prior_args)

    def forget(self) -> None:
        """Drop the rows `features_cached` remembers (call it whenever a canvas row, the
        particle indices or the target change: SMC calls it at the start of every step)."""
        self._rows.clear()

    def features_cached(
        self,
        sites: list[Site],
        canvas: Canvas | None,
        idx: list[int],
        turtles: list[Turtle],
        depths: list[float],
        params: list[np.ndarray],
        prior_args: list[np.ndarray],
    ) -> list[np.ndarray]:
        """`features_round` with the site-independent columns remembered per particle: a
        particle asked again at the same turtle state (and, until `forget`, the same canvas
        row) reuses its turtle and window columns (only its depth column is written anew);
        the others are computed in one pass. Every row equals the one `features_round`
        gives (tests/runtime/image/test_features.py)."""
        known = self._rows  # particle -> the turtle state its row in `_block` is for
        n = len(idx)
        miss = [
            j
            for j, (i, turtle) in enumerate(zip(idx, turtles, strict=True))
            if known.get(i) != turtle
        ]
        ia = np.array(idx, dtype=np.intp)
        top = max(idx) + 1
        if self._block.shape[0] < top:
            grown = np.empty(
                (max(top, 2 * self._block.shape[0]), self._block.shape[1]), dtype=np.float32
            )
            grown[: self._block.shape[0]] = self._block
            self._block = grown
        if len(miss) == n:
            common = self._common(
                canvas,
                ia,
                np.array(turtles, dtype=np.float64).reshape(n, 4),
                np.array(depths, dtype=np.float64),
            )
            self._block[ia] = common
        else:
            if miss:
                sel = ia[miss]
                self._block[sel] = self._common(
                    canvas,
                    sel,
                    np.array([turtles[j] for j in miss], dtype=np.float64).reshape(-1, 4),
                    np.zeros(len(miss)),
                )
            common = self._block[ia]
            # the depth column differs between a particle's sites at one turtle state
            common[:, 6] = np.array(depths, dtype=np.float64) / self.derivation_length
        for j in miss:
            known[idx[j]] = turtles[j]
        return self._site_rows(sites, common, params, prior_args)

    def _site_rows(
        self,
        sites: list[Site],
        common: np.ndarray,
        params: list[np.ndarray],
        prior_args: list[np.ndarray],
    ) -> list[np.ndarray]:
        """Each site's rows: the common columns with its module parameters and prior
        arguments put in after the first N_LOCAL_BASE."""
        n = len(common)
        out = []
        pos = 0
        for site, par, args in zip(sites, params, prior_args, strict=True):
            m = len(args)
            a, k = int(site.arity), int(site.n_args())
            block = common[pos : pos + m]
            rows = np.concatenate(
                (
                    block[:, :N_LOCAL_BASE],
                    _fit_columns(par, m, a),
                    _fit_columns(args, m, k),
                    block[:, N_LOCAL_BASE:],
                ),
                axis=1,
                dtype=np.float32,
            )
            out.append(rows)
            pos += m
        if pos != n:
            raise ValueError(f"features: {n} particles, {pos} rows of arguments")
        return out

    def _common(
        self, canvas: Canvas | None, idx: np.ndarray, turtle: np.ndarray, depth: np.ndarray
    ) -> np.ndarray:
        """(n, 7 + 72 [+ 17]) float32: the site-independent columns (turtle state, depth,
        target and partial windows, context) of every particle, in few numpy calls (SMC's
        batches are small)."""
        n = len(idx)
        # (u, v): normalized image position, u right, v down from ymax
        uv = (turtle[:, :2] - self._origin) / self._span
        out = np.empty((n, self.n_common), dtype=np.float32)
        out[:, :2] = uv * _TWO_NEG + _ONE_POS  # 2u - 1, 1 - 2v
        heading = turtle[:, 2]
        out[:, 2] = np.mod(heading, 360.0) / 180.0 - 1.0
        rad = np.radians(heading)
        out[:, 3] = np.sin(rad)
        out[:, 4] = np.cos(rad)
        out[:, 5] = turtle[:, 3]
        out[:, 6] = depth / self.derivation_length
        nl = N_LOCAL_BASE
        target = out[:, nl : nl + N_WINDOW]
        partial = out[:, nl + N_WINDOW : nl + 2 * N_WINDOW]
        h, w = self._shape(canvas)
        if self.context:
            out[:, nl + 2 * N_WINDOW :] = 0.0
        if h == 0 or w == 0:
            target[:] = 0.0 if self.target_levels is None else -1.0
            partial[:] = 0.0 if canvas is None else -1.0
            return out
        if not np.isfinite(uv).all():
            uv = np.column_stack(_unit(uv[:, 0], uv[:, 1]))
        size, low, high, mult, offs = self._windows(h, w)
        # the turtle's (row, col) at each level, clipped to the padding (a window centred 2
        # cells outside lies wholly outside, like one further out): (n, 2, L)
        rc = np.floor(uv[:, ::-1, None] * size)
        np.maximum(rc, low, out=rc)
        np.minimum(rc, high, out=rc)
        # (n, L * 9) indices into the padded pyramid (target's and every canvas's row)
        at = ((rc * mult).sum(axis=1).astype(np.intp)[:, :, None] + offs).reshape(n, N_WINDOW)
        if self.target_levels is None:
            target[:] = 0.0
        else:
            target[:] = self._padded_target()[at]
        if canvas is None:
            partial[:] = 0.0
        else:
            partial[:] = canvas.padded[idx[:, None], at]
        if self.context and self.target_levels is not None and canvas is not None:
            self._context(out[:, nl + 2 * N_WINDOW :], canvas, idx, uv, heading, h, w)
        return out

    def _context_geometry(self, h: int, w: int) -> ContextGeometry:
        """Per canvas size: the fill level's cells in the padded row, the target there and
        its sum; per look-ahead group (the context's, then the far one's) its (angle,
        distance) pairs and its level's first cell (start + padding), padded width, height
        and width; the viewport's aspect."""
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
            rays = [
                (
                    np.repeat(np.asarray(RAY_ANGLES), len(d)),
                    np.tile(np.asarray(d), len(RAY_ANGLES)),
                    int(starts[lv] + PAD * wp[lv] + PAD),
                    int(wp[lv]),
                    h >> lv,
                    w >> lv,
                )
                for d, lv in groups
            ]
            aspect = -self._span[0] / self._span[1]  # viewport width / height
            self._context_geom[key] = (cells, t, max(float(t.sum()), 1e-6), rays, aspect)
        return self._context_geom[key]

    def _context(
        self,
        out: np.ndarray,
        canvas: Canvas,
        idx: np.ndarray,
        uv: np.ndarray,
        heading: np.ndarray,
        h: int,
        w: int,
    ) -> None:
        """The context group (module docstring), and the far group after it, of n particles
        into `out` (n, N_CONTEXT [+ N_FAR])."""
        cells, t, total, rays, aspect = self._context_geometry(h, w)
        d = t - canvas.padded[idx[:, None], cells]
        unfilled = np.maximum(d, 0.0).sum(axis=1)
        out[:, 0] = unfilled / total
        out[:, 1] = (unfilled - d.sum(axis=1)) / total  # sum of max(-d, 0)
        col0 = 2
        for angles, dist, base, wp, hl, wl in rays:
            # (n, R) look-ahead cells; one outside the image lands in the padding (-1 in the
            # target's row), and so does one of a heading that is not finite (fmax: NaN -> -1)
            ang = np.radians(heading[:, None] + angles)
            row = np.floor((uv[:, 1:] - np.sin(ang) * dist * aspect) * hl)
            col = np.floor((uv[:, :1] + np.cos(ang) * dist) * wl)
            np.fmax(row, -1.0, out=row)
            np.fmin(row, hl, out=row)
            np.fmax(col, -1.0, out=col)
            np.fmin(col, wl, out=col)
            at = (row * wp + col).astype(np.intp) + base
            tv = self._padded_target()[at]
            ahead = np.maximum(tv - canvas.padded[idx[:, None], at], 0.0)
            out[:, col0 : col0 + len(angles)] = np.where(tv < 0, -1.0, ahead)
            col0 += len(angles)
