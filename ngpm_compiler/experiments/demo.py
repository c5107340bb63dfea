"""`ngpmc demo`: grow guided and unguided vines into the built-in targets, side by side.

Each configuration runs `--runs` times (seeds seed, seed+1, ...): the table gives the mean
similarity and seconds over the runs, the pictures show the median run. Writes `demo.png`
(rows: targets; columns: target | guided | unguided, similarity and seconds under each),
one render of each median run and `summary.md`, and prints the summary. Then the 3D rows
(experiments/demo3d.py): the bundled vines3d vine grown into 3D targets, guided and
unguided at about the same time, drawn below the 2D rows and tabulated after them. Uses only
the package data (ngpm_runtime.bundled) and targets made here: nothing is trained or
downloaded.

The command is ngpm_compiler.cli.demo; the targets: ngpm_compiler.datasets.demo_targets.
"""

from __future__ import annotations

import io
import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from ngpm_runtime.errors import NgpmError
from ngpm_runtime.files import atomic_write
from ngpm_runtime.geometry.turtle import Prim
from ngpm_runtime.image.targets import Target
from PIL import Image, ImageDraw, ImageFont

from ngpm_compiler.experiments.demo3d import UNGUIDED_FACTOR, Demo3DRow

CELL = 220  # pixels per picture in demo.png
CAPTION = 34  # caption height under each picture
HEADER = 26
PAD = 8


class DemoError(NgpmError):
    """The demo cannot run or write its output."""


# --------------------------------------------------------------------------- running


@dataclass
class DemoRow:
    target: Target
    guided_runs: list[Any]  # ngpm_runtime.grow.GrowResult per seed
    unguided_runs: list[Any]

    @property
    def guided(self) -> Any:
        """The median guided run (by similarity)."""
        return median_run(self.guided_runs)

    @property
    def unguided(self) -> Any:
        return median_run(self.unguided_runs)


def median_run(runs: list[Any]) -> Any:
    """The run with the median similarity (the lower middle one for an even count)."""
    return sorted(runs, key=lambda r: r.similarity)[(len(runs) - 1) // 2]


def run_demo(
    particles: int = 10, seed: int = 0, program: Any = None, guide: Any = None, runs: int = 3
) -> tuple[list[DemoRow], Any]:
    """Guided and unguided SMC on every built-in target; returns the rows and the guide.

    program and guide default to the bundled vines model and guide."""
    from ngpm_runtime.bundled import bundled_guide, bundled_program, demo_targets
    from ngpm_runtime.grow import grow

    program = bundled_program() if program is None else program
    guide = bundled_guide(program) if guide is None else guide
    rows = []
    for target in demo_targets():
        seeds = range(seed, seed + runs)
        rows.append(
            DemoRow(
                target,
                [grow(program, target, guide, particles, s) for s in seeds],
                [grow(program, target, None, particles, s) for s in seeds],
            )
        )
    return rows, guide


def prepare_out_dir(path: str | os.PathLike[str]) -> Path:
    """Create the output folder and check that it is writable, before any work."""
    out = Path(path)
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=out, prefix=".ngpm_demo_probe.")
        os.close(fd)
        os.unlink(probe)
    except OSError as err:
        raise DemoError(
            f"{out}: cannot write the demo output there ({err.strerror or err.__class__.__name__})"
        ) from None
    return out


# --------------------------------------------------------------------------- summary


def _stats(runs: list[Any]) -> tuple[str, str]:
    """Mean similarity and mean seconds over runs, formatted."""
    sim = float(np.mean([r.similarity for r in runs]))
    return f"{sim:.3f}", f"{float(np.mean([r.seconds for r in runs])):.2f}"


def _mean(rows: Sequence[DemoRow | Demo3DRow], kind: str) -> tuple[str, str]:
    return _stats([r for row in rows for r in getattr(row, f"{kind}_runs")])


def summary_table(rows: list[DemoRow], particles: int, runs: int = 1) -> str:
    head = ("target", f"guided N={particles}", "seconds", f"unguided N={particles}", "seconds")
    return (
        f"similarity (1 = the target exactly, 0 = no better than a blank canvas) and "
        f"seconds, mean of {runs} run{'s' if runs > 1 else ''}\n" + _text_table(head, rows)
    )


def summary_table3d(rows: Sequence[Demo3DRow], particles: int) -> str:
    """The 3D rows as summary_table's text table (the unguided runs' N in the header)."""
    n_u = UNGUIDED_FACTOR * particles
    head = ("3D target", f"guided N={particles}", "seconds", f"unguided N={n_u}", "seconds")
    return _text_table(head, rows)


def _text_table(head: tuple[str, ...], rows: Sequence[DemoRow | Demo3DRow]) -> str:
    """Aligned columns: name, guided similarity and seconds, unguided ones; then the mean."""
    body = [(r.target.name, *_stats(r.guided_runs), *_stats(r.unguided_runs)) for r in rows]
    body.append(("mean", *_mean(rows, "guided"), *_mean(rows, "unguided")))
    widths = [max(len(x[i]) for x in [head, *body]) for i in range(len(head))]
    lines = [
        "  ".join(
            c.ljust(w) if i == 0 else c.rjust(w)
            for i, (c, w) in enumerate(zip(r, widths, strict=True))
        )
        for r in [head, *body]
    ]
    lines.insert(1, "-" * len(lines[0]))
    return "\n".join(lines)


def summary_markdown(
    rows: list[DemoRow],
    guide: Any,
    particles: int,
    seed: int,
    runs: int = 1,
    rows3d: Sequence[Demo3DRow] = (),
    guide3d: Any = None,
) -> str:
    from ngpm_runtime.bundled import guide_summary

    program = guide.program
    seeds = f"seed {seed}" if runs == 1 else f"seeds {seed} to {seed + runs - 1}"
    lines = [
        "# ngpm demo: guided vs unguided SMC",
        "",
        f"Grammar `{program.name}` ({program.grammar_hash[:19]}...), {particles} particles per "
        f"run, {runs} run{'s' if runs > 1 else ''} per target and kind ({seeds}). "
        f"Guide: `{Path(guide.path).name}` ({guide_summary(guide)}).",
        "",
        "Similarity is the paper's normalized shape similarity of the best particle: 1 is the "
        "target exactly, 0 is no better than a blank canvas. The table gives the mean over the "
        "runs; the pictures show the median run. Seconds are each SMC run's wall-clock time; "
        "unguided runs are short because under the prior most vines stop after a few "
        "branches.",
        "",
        f"| target | guided N={particles} | seconds | unguided N={particles} | seconds |",
        "|---|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r.target.name} | {' | '.join(_stats(r.guided_runs))} | "
            f"{' | '.join(_stats(r.unguided_runs))} |"
        )
    lines.append(
        f"| **mean** | {' | '.join(_mean(rows, 'guided'))} | "
        f"{' | '.join(_mean(rows, 'unguided'))} |"
    )
    lines.append("")
    lines.append("Every run (similarity):")
    lines.append("")
    for r in rows:
        g = ", ".join(f"{x.similarity:.3f}" for x in r.guided_runs)
        u = ", ".join(f"{x.similarity:.3f}" for x in r.unguided_runs)
        lines.append(f"- {r.target.name}: guided {g}; unguided {u}")
    if rows3d:
        lines += ["", *markdown3d(rows3d, guide3d, particles)]
    lines += [
        "",
        "![comparison](demo.png)",
        "",
        "Grow a vine into your own picture: `ngpmc grow picture.png -o vine.png`.",
        "",
    ]
    return "\n".join(lines)


def markdown3d(rows: Sequence[Demo3DRow], guide: Any, particles: int) -> list[str]:
    """summary.md's 3D section: the setting, the table (its mean row `**mean 3D**`) and
    every run (lines `- NAME (3D): ...`)."""
    from ngpm_runtime.bundled import guide_summary

    from ngpm_compiler.experiments.demo3d import RESOLUTION

    n_u = UNGUIDED_FACTOR * particles
    lines = [
        "## 3D",
        "",
        f"Grammar `{guide.program.name}` ({guide.program.grammar_hash[:19]}...) grown into "
        f"{len(rows)} 3D targets at {RESOLUTION}^3 voxels it was not trained on, guided with "
        f"{particles} particles (guide `{Path(guide.path).name}`: {guide_summary(guide)}) "
        f"and unguided with {n_u}, which take about as long; same seeds. Similarity is the "
        "same normalized shape similarity on voxels. The pictures (below the 2D rows) show "
        "the median runs from one view at one scale.",
        "",
        f"| 3D target | made from | guided N={particles} | seconds | unguided N={n_u} | seconds |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r.target.name} | {r.source} | {' | '.join(_stats(r.guided_runs))} | "
            f"{' | '.join(_stats(r.unguided_runs))} |"
        )
    lines.append(
        f"| **mean 3D** | | {' | '.join(_mean(rows, 'guided'))} | "
        f"{' | '.join(_mean(rows, 'unguided'))} |"
    )
    lines += ["", "Every 3D run (similarity):", ""]
    for r in rows:
        g = ", ".join(f"{x.similarity:.3f}" for x in r.guided_runs)
        u = ", ".join(f"{x.similarity:.3f}" for x in r.unguided_runs)
        lines.append(f"- {r.target.name} (3D): guided {g}; unguided {u}")
    return lines


# --------------------------------------------------------------------------- pictures


# Debian's fonts-dejavu-core, for a plain `pip install .` (matplotlib comes with the extras)
DEBIAN_DEJAVU = Path("/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf")


def _font(size: int) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    """DejaVu Sans from matplotlib or Debian, else Pillow's own font."""
    paths = [DEBIAN_DEJAVU]
    try:
        import matplotlib

        paths.insert(0, Path(matplotlib.get_data_path()) / "fonts" / "ttf" / "DejaVuSans.ttf")
    except ImportError:
        pass
    for path in paths:
        try:
            return ImageFont.truetype(str(path), size)
        except OSError:
            continue
    try:
        return ImageFont.load_default(size)  # Pillow >= 10.1: scalable
    except TypeError:
        return ImageFont.load_default()


def _render(prims: list[Prim], viewport: Any, mask: np.ndarray, size: int) -> np.ndarray:
    from ngpm_runtime.image.render import render_array

    return render_array(prims, viewport, size, target_mask=mask)


def target_picture(target: Target, size: int) -> np.ndarray:
    """The target mask (dark gray on white) with its start as a red arrow from a green dot."""
    from ngpm_compiler.datasets.sheets import draw_start

    tile = np.where(target.mask, 70, 255).astype(np.uint8)
    img = Image.fromarray(tile, mode="L").resize((size, size), Image.Resampling.NEAREST)
    img = img.convert("RGB")
    draw = ImageDraw.Draw(img)
    sx, sy, dx, dy = target.start
    px, py = sx * size, sy * size
    draw_start(draw, px, py, dx, dy, 0.16 * size, head=0.4, width=3, dot=5)
    return np.asarray(img)


def row_pictures(row: Demo3DRow, size: int) -> list[np.ndarray]:
    """A 3D row's target | guided | unguided (median runs) as three RGB (size, size, 3)
    pictures of one view, drawn at one scale (image/render3d.render_side_by_side)."""
    from ngpm_runtime.geometry.mesh import mesh_from_primitives
    from ngpm_runtime.image.render3d import render_side_by_side

    trees = [median_run(runs).primitives for runs in (row.guided_runs, row.unguided_runs)]
    meshes = [row.target.mesh(), *(mesh_from_primitives(p) for p in trees)]
    strip = render_side_by_side(meshes, size)
    return [strip[:, k * size : (k + 1) * size] for k in range(3)]


def comparison_image(
    rows: list[DemoRow], particles: int, viewport: Any, rows3d: Sequence[Demo3DRow] = ()
) -> np.ndarray:
    """RGB array: one row per target, columns target | guided | unguided (median runs),
    with captions; then, under a header of their own, the 3D rows."""
    if not rows:
        raise DemoError("no demo targets to draw")
    cols = 3
    width = PAD + cols * (CELL + PAD)
    height = HEADER + len(rows) * (CELL + CAPTION + PAD) + PAD
    if rows3d:
        height += HEADER + len(rows3d) * (CELL + CAPTION + PAD)
    sheet = Image.new("RGB", (width, height), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    runs = len(rows[0].guided_runs)
    median = f", median of {runs}" if runs > 1 else ""
    heads = ("target", f"guided, N={particles}{median}", f"unguided, N={particles}{median}")
    _heads(draw, heads, 0)
    for r, row in enumerate(rows):
        pics = [
            target_picture(row.target, CELL),
            _render(row.guided.primitives, viewport, row.target.mask, CELL),
            _render(row.unguided.primitives, viewport, row.target.mask, CELL),
        ]
        _cells(
            sheet, draw, HEADER + r * (CELL + CAPTION + PAD), pics, _captions(row, row.target.name)
        )
    if rows3d:
        y0 = HEADER + len(rows) * (CELL + CAPTION + PAD)
        n_u = UNGUIDED_FACTOR * particles
        heads = (
            "3D target (voxels)",
            f"guided, N={particles}{median}",
            f"unguided, N={n_u}{median}",
        )
        _heads(draw, heads, y0)
        for r, row3 in enumerate(rows3d):
            y = y0 + HEADER + r * (CELL + CAPTION + PAD)
            _cells(sheet, draw, y, row_pictures(row3, CELL), _captions(row3, row3.target.name))
    return np.asarray(sheet)


def _heads(draw: ImageDraw.ImageDraw, heads: Sequence[str], y0: int) -> None:
    """Column titles in a HEADER-high band starting at y0."""
    title = _font(15)
    for c, text in enumerate(heads):
        draw.text(
            (PAD + c * (CELL + PAD) + CELL / 2, y0 + HEADER / 2),
            text,
            fill=(0, 0, 0),
            font=title,
            anchor="mm",
        )


def _captions(row: DemoRow | Demo3DRow, name: str) -> list[str]:
    g, u = median_run(row.guided_runs), median_run(row.unguided_runs)
    return [
        name,
        f"similarity {g.similarity:.3f}, {g.seconds:.2f} s",
        f"similarity {u.similarity:.3f}, {u.seconds:.2f} s",
    ]


def _cells(
    sheet: Image.Image,
    draw: ImageDraw.ImageDraw,
    y0: int,
    pics: Sequence[np.ndarray],
    caps: Sequence[str],
) -> None:
    """One row of pictures (resized to CELL) with their captions, from height y0."""
    small = _font(13)
    for c, (pic, cap) in enumerate(zip(pics, caps, strict=True)):
        x0 = PAD + c * (CELL + PAD)
        tile = Image.fromarray(np.ascontiguousarray(pic))
        if tile.size != (CELL, CELL):
            tile = tile.resize((CELL, CELL), Image.Resampling.LANCZOS)
        sheet.paste(tile, (x0, y0))
        draw.rectangle((x0, y0, x0 + CELL - 1, y0 + CELL - 1), outline=(200, 200, 200))
        draw.text(
            (x0 + CELL / 2, y0 + CELL + CAPTION / 2),
            cap,
            fill=(0, 0, 0),
            font=small,
            anchor="mm",
        )


def _save_png(rgb: np.ndarray, path: Path) -> None:
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format="PNG", optimize=True)
    atomic_write(path, buf.getvalue())


def _write_text(path: Path, text: str) -> None:
    atomic_write(path, text)


def write_demo(
    out_dir: str | os.PathLike[str],
    particles: int = 10,
    seed: int = 0,
    runs: int = 3,
    program: Any = None,
    guide: Any = None,
    guide3d: Any = None,
    with_3d: bool = True,
) -> tuple[list[DemoRow], list[Demo3DRow], list[Path]]:
    """Run the demo and write its renders, `demo.png` and `summary.md` into `out_dir`.

    program, guide: default to the bundled vines model and its guide; guide3d: to the
    bundled vines3d guide (its program is the 3D rows' grammar); with_3d=False leaves the
    3D rows out. Returns (rows, 3D rows, files written: the renders, then demo.png and
    summary.md)."""
    from ngpm_runtime.bundled import bundled_guide, bundled_guide3d, bundled_program

    from ngpm_compiler.experiments.demo3d import run_demo3d

    if particles < 1:
        raise DemoError("-N must be at least 1")
    if runs < 1:
        raise DemoError("--runs must be at least 1")
    program = bundled_program() if program is None else program
    guide = bundled_guide(program) if guide is None else guide
    if with_3d and guide3d is None:
        guide3d = bundled_guide3d()
    out = prepare_out_dir(out_dir)
    rows, _ = run_demo(particles, seed, program, guide, runs)
    rows3d = run_demo3d(particles, seed, runs, guide3d.program, guide3d) if with_3d else []
    files = []
    for row in rows:
        for kind, res in (("guided", row.guided), ("unguided", row.unguided)):
            path = out / f"{row.target.name}_{kind}.png"
            _save_png(_render(res.primitives, program.viewport, row.target.mask, 512), path)
            files.append(path)
    for row3 in rows3d:
        path = out / f"{row3.target.name}.png"  # target | guided | unguided
        _save_png(np.concatenate(row_pictures(row3, 384), axis=1), path)
        files.append(path)
    sheet = out / "demo.png"
    _save_png(comparison_image(rows, particles, program.viewport, rows3d), sheet)
    text = summary_markdown(rows, guide, particles, seed, runs, rows3d, guide3d)
    _write_text(out / "summary.md", text)
    return rows, rows3d, [*files, sheet, out / "summary.md"]
