"""Plots (matplotlib, Agg) of the evaluation: paper Figures 4a, 4b, 5a, 5b and result grids.

Every function takes plain rows (the CSV dicts of evaluation/runs.py) and writes one PNG atomically.
"""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Any

import numpy as np
from ngpm_runtime.files import atomic_write

from ngpm_compiler.evaluation.runs import UNGUIDED, curve

COLORS = {
    UNGUIDED: "#444444",
    "const": "#1f77b4",
    "local": "#ff7f0e",
    "local+target": "#2ca02c",
    "all": "#d62728",
    "all_k1": "#9467bd",
}
LABELS = {
    UNGUIDED: "unguided",
    "const": "constant params",
    "local": "+ local state",
    "local+target": "+ target features",
    "all": "all features (K=4)",
    "all_k1": "all features (K=1)",
}


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_fig(fig: Any, path: str | Path, dpi: int = 100) -> Path:
    """Save a figure as PNG (atomically) and close it."""
    plt = _plt()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return atomic_write(path, buf.getvalue())


def label(model: str) -> str:
    return LABELS.get(model, model)


def plot_similarity_vs_n(
    summary: list[dict[str, Any]], models: list[str], path: str | Path, title: str
) -> Path:
    """Mean (over targets) of the median similarity vs N, with 95% CI bands (Fig. 4a / 5a)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for m in models:
        rows = sorted((r for r in summary if r["model"] == m), key=lambda r: int(r["n"]))
        if not rows:
            continue
        n = np.array([int(r["n"]) for r in rows])
        mean = np.array([float(r["mean_similarity"]) for r in rows])
        lo = np.array([float(r["ci_low"]) for r in rows])
        hi = np.array([float(r["ci_high"]) for r in rows])
        c = COLORS.get(m)
        ax.plot(n, mean, "o-", color=c, label=label(m), ms=4)
        ax.fill_between(n, lo, hi, color=c, alpha=0.15, lw=0)
    ax.set_xscale("log")
    ax.set_xlabel("number of particles N")
    ax.set_ylabel("similarity (mean of per-target medians)")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    return save_fig(fig, path)


def plot_time_vs_similarity(
    summary: list[dict[str, Any]],
    speed_rows: list[dict[str, Any]],
    models: list[str],
    path: str | Path,
) -> Path:
    """Left: mean wall time vs mean similarity per model (Fig. 4b). Right: speedups."""
    plt = _plt()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10.5, 4.0))
    for m in [UNGUIDED, *models]:
        n, s, t = curve(summary, m)
        if not len(n):
            continue
        ax.plot(s, t, "o-", color=COLORS.get(m), label=label(m), ms=3)
    ax.set_yscale("log")
    ax.set_xlabel("similarity reached (mean over targets)")
    ax.set_ylabel("wall time per SMC run (s)")
    ax.set_title("Time vs similarity")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    for m in models:
        rows = [r for r in speed_rows if r["model"] == m and r["speedup"] != ""]
        if not rows:
            continue
        thr = np.array([float(r["threshold"]) for r in rows])
        sp = np.array([float(r["speedup"]) for r in rows])
        lower = np.array([r["bound"] == ">" for r in rows])
        bx.plot(thr, sp, "o-", color=COLORS.get(m), label=label(m), ms=3)
        if lower.any():
            bx.plot(thr[lower], sp[lower], "^", color=COLORS.get(m), ms=7, mfc="none")
    bx.axhline(1.0, color="k", lw=0.8)
    bx.axhline(10.0, color="k", lw=0.8, ls="--")
    bx.set_yscale("log")
    bx.set_xlabel("similarity threshold")
    bx.set_ylabel("speedup over unguided (time ratio)")
    bx.set_title("Speedup at equal similarity (open triangle: lower bound)")
    bx.grid(True, which="both", alpha=0.3)
    if bx.get_legend_handles_labels()[0]:
        bx.legend(fontsize=8)
    return save_fig(fig, path)


def plot_trainset_size(
    points: list[dict[str, Any]],
    unguided: dict[str, float] | None,
    path: str | Path,
    n_particles: int,
) -> Path:
    """Similarity at N = n_particles vs the number of training traces (Fig. 5b)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.0, 4.0))
    pts = sorted(points, key=lambda r: int(r["traces"]))
    x = np.array([int(r["traces"]) for r in pts])
    y = np.array([float(r["mean_similarity"]) for r in pts])
    lo = np.array([float(r["ci_low"]) for r in pts])
    hi = np.array([float(r["ci_high"]) for r in pts])
    ax.errorbar(
        x,
        y,
        yerr=[y - lo, hi - y],
        fmt="o-",
        color=COLORS["all"],
        capsize=3,
        label=f"all features, N = {n_particles}",
    )
    if unguided:
        ax.axhline(
            unguided["mean_similarity"],
            color=COLORS[UNGUIDED],
            ls="--",
            label=f"unguided, N = {n_particles}",
        )
    ax.set_xscale("log")
    ax.set_xlabel("training traces")
    ax.set_ylabel("similarity (mean of per-target medians)")
    ax.set_title("Training-set size")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    return save_fig(fig, path)


def image_grid(
    rows: list[list[dict[str, Any]]],
    path: str | Path,
    cell: float = 1.9,
    header: list[str] | None = None,
) -> Path:
    """A grid of RGB images: rows of cells {"image": (h, w, 3) uint8, "caption": str}."""
    plt = _plt()
    n_rows = len(rows)
    n_cols = max(len(r) for r in rows)
    fig, axes = plt.subplots(
        n_rows, n_cols, figsize=(cell * n_cols, cell * 1.22 * n_rows), squeeze=False
    )
    for i, row in enumerate(rows):
        for j in range(n_cols):
            ax = axes[i][j]
            ax.set_xticks([])
            ax.set_yticks([])
            if j >= len(row):
                ax.axis("off")
                continue
            c = row[j]
            ax.imshow(c["image"], interpolation="bilinear")
            ax.set_xlabel(c.get("caption", ""), fontsize=7.5)
            if i == 0 and header and j < len(header):
                ax.set_title(header[j], fontsize=8.5)
            for sp in ax.spines.values():
                sp.set_color("#bbbbbb")
    fig.tight_layout(pad=0.4)
    return save_fig(fig, path, dpi=80)


def target_image(mask: np.ndarray, size: int) -> np.ndarray:
    """The target mask as a dark-on-white RGB image, `size` pixels square (nearest)."""
    m = np.asarray(mask, dtype=bool)
    rows = (np.arange(size) * m.shape[0]) // size
    cols = (np.arange(size) * m.shape[1]) // size
    big = m[rows[:, None], cols[None, :]]
    img = np.full((size, size, 3), 255, np.uint8)
    img[big] = (70, 70, 70)
    return img


def fmt_secs(s: float) -> str:
    if not math.isfinite(s):
        return "-"
    return f"{s:.2f} s" if s < 10 else f"{s:.1f} s"
