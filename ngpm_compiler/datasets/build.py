"""Target datasets: the registry of sets (`DATASETS`) and `build_dataset`, which writes one.

Every family's builder (scribbles.py, varied.py, glyphs.py, silhouettes.py, clipart.py)
yields `(Target, source)` pairs; `build_dataset` writes them as `NAME_0000.png` +
`NAME_0000.txt` (the sidecar) plus `index.json`, one file at a time (atomic writes),
skipping files that already exist, so an interrupted build resumes. Nothing is downloaded:
fonts and silhouettes come from files on this machine. Contact sheets: sheets.py. The 3D
sets (sets3d.py, `dim` 3) yield `VolumeTarget`s, written as `NAME_0000.npz` with a picture
`NAME_0000.png`, at `resolution` voxels a side.
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from ngpm_runtime.files import atomic_write
from ngpm_runtime.image.targets import Target, save_target, sidecar_path
from ngpm_runtime.volume.target import VolumeTarget

from ngpm_compiler.datasets.clipart import build_clipart
from ngpm_compiler.datasets.common import DatasetError, DatasetWarning
from ngpm_compiler.datasets.envelopes import build_envelopes, grammar_sha
from ngpm_compiler.datasets.glyphs import build_glyphs
from ngpm_compiler.datasets.scribbles import build_scribbles
from ngpm_compiler.datasets.sets3d import (
    build_blobs3d,
    build_extruded,
    build_revolved,
    mirrored3d,
    save_volume,
)
from ngpm_compiler.datasets.silhouettes import build_shapes, build_silhouettes
from ngpm_compiler.datasets.varied import build_varied


@dataclass(frozen=True)
class DatasetSpec:
    name: str
    description: str
    default_count: int | None  # None: every item the source provides
    builder: Callable[..., Iterator[Any]]  # Items, or (VolumeTarget, source) when dim is 3
    dim: int = 2


DATASETS: dict[str, DatasetSpec] = {
    "scribbles": DatasetSpec(
        "scribbles",
        "synthetic hand-drawn-looking strokes, start where the stroke began (training)",
        300,
        build_scribbles,
    ),
    "glyphs": DatasetSpec(
        "glyphs",
        "font glyphs with one connected component (default DejaVu Sans Bold; "
        "--font PATH for any TTF/OTF), automatic start (testing)",
        None,
        build_glyphs,
    ),
    "silhouettes": DatasetSpec(
        "silhouettes",
        "images from --from DIR, scikit-image's horse and procedural animal "
        "and object silhouettes, automatic start unless a sidecar exists (testing)",
        None,
        build_silhouettes,
    ),
    "shapes": DatasetSpec(
        "shapes",
        "procedural animal and object silhouettes (those of `silhouettes` without "
        "the horse; use another --seed than a test set's), automatic start (training)",
        300,
        build_shapes,
    ),
    "varied": DatasetSpec(
        "varied",
        "synthetic strokes of width 1-6 px, thin script-like loops, filled blobs "
        "and 2-3 disjoint parts, start where the first stroke began (training)",
        300,
        build_varied,
    ),
    "envelopes": DatasetSpec(
        "envelopes",
        "filled silhouettes of --grammar FILE's own forward samples in its viewport, "
        "start at the grammar's start (training; held out: another --seed)",
        300,
        build_envelopes,
    ),
    "clipart": DatasetSpec(
        "clipart",
        "silhouettes of public-domain clip art (default: Openclipart animals from "
        "Debian's openclipart-svg, --from DIR for others), automatic start (testing)",
        None,
        build_clipart,
    ),
    "blobs3d": DatasetSpec(
        "blobs3d",
        "3D: random unions of 2-5 spheres, boxes, capsules and cones, automatic start (training)",
        300,
        build_blobs3d,
        3,
    ),
    "extruded": DatasetSpec(
        "extruded",
        "3D: scribbles, varied strokes and glyphs extruded to a random depth, "
        "start where the 2D target starts (training)",
        300,
        build_extruded,
        3,
    ),
    "revolved": DatasetSpec(
        "revolved",
        "3D: procedural silhouettes (or --from DIR pictures, e.g. Openclipart) revolved "
        "about their vertical middle, automatic start (testing)",
        None,
        build_revolved,
        3,
    ),
}


def build_dataset(
    name: str,
    out_dir: str | os.PathLike[str],
    count: int | None = None,
    seed: int = 0,
    size: int = 50,
    font: str | os.PathLike[str] | None = None,
    source_dir: str | os.PathLike[str] | None = None,
    mirror: bool = False,
    polarity: str = "auto",
    resolution: int = 32,
    grammar: str | os.PathLike[str] | None = None,
) -> list[Path]:
    """Build dataset `name` into out_dir; returns the PNG paths (the .npz paths of a 3D
    set, made at `resolution` voxels a side; `size` is for 2D sets) in index order.

    Existing `NAME_####.png` files with sidecars are kept as they are (resume). Source
    items that cannot be used are skipped with a DatasetWarning. With mirror=True every
    target also gets a mirrored copy `NAME_####_m.png`. `grammar`: envelopes' .lsys file.
    """
    spec = DATASETS.get(name)
    if spec is None:
        raise DatasetError(f"unknown dataset {name!r}; choose from {', '.join(DATASETS)}")
    if count is None:
        count = spec.default_count
    if count is not None and count < 0:
        raise DatasetError("count must be >= 0")
    if not isinstance(size, int) or size < 8:
        raise DatasetError("size must be an integer >= 8")
    if spec.dim == 3 and (isinstance(resolution, bool) or not 8 <= resolution <= 128):
        raise DatasetError("resolution must be an integer from 8 to 128")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    params = {
        "name": name,
        "seed": seed,
        **({"resolution": resolution} if spec.dim == 3 else {"size": size}),
        "mirror": mirror,
        "font": str(font) if font is not None else None,
        "source_dir": str(source_dir) if source_dir is not None else None,
        **_grammar_params(name, grammar),
    }
    _check_previous(out / "index.json", params)
    _write_index(out, {**params, "complete": False, "files": []})
    files: list[Path] = []
    sources: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DatasetWarning)
        items = spec.builder(
            count=count,
            seed=seed,
            size=size,
            resolution=resolution,
            font=font,
            source_dir=source_dir,
            polarity=polarity,
            grammar=grammar,
        )
        write = _write_volume if spec.dim == 3 else _write_target
        for i, (target, source) in enumerate(items):
            for path, mirrored in write(target, out, f"{name}_{i:04d}", mirror):
                files.append(path)
                sources.append(source + (" (mirrored)" if mirrored else ""))
    skipped = [str(w.message) for w in caught if issubclass(w.category, DatasetWarning)]
    for w in caught:  # hand the warnings on to whoever called us
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    _write_index(
        out,
        {
            **params,
            "source": spec.description,
            "count": len(files),
            "complete": True,
            "skipped": len(skipped),
            "skipped_reasons": skipped,
            "files": [p.name for p in files],
            "sources": sources,
        },
    )
    return files


def _grammar_params(name: str, grammar: str | os.PathLike[str] | None) -> dict[str, Any]:
    """The grammar of an `envelopes` build ({} for other sets, whose index has none)."""
    if name != "envelopes":
        return {}
    if grammar is None:
        raise DatasetError("envelopes are made from a grammar's samples: give --grammar FILE")
    if not Path(grammar).is_file():
        raise DatasetError(f"{grammar}: no such grammar file")
    return {"grammar": Path(grammar).name, "grammar_sha": grammar_sha(grammar)}


def _write_target(target: Target, out: Path, stem: str, mirror: bool) -> list[tuple[Path, bool]]:
    """Write a 2D target (and its mirror) unless there already; (path, mirrored) each."""
    named = Target(target.mask, target.start, stem)
    done = []
    for t in [named, named.mirrored()] if mirror else [named]:
        path = out / f"{t.name}.png"
        if not (path.is_file() and sidecar_path(path).is_file()):
            save_target(t, path)
        done.append((path, t is not named))
    return done


def _write_volume(
    target: VolumeTarget, out: Path, stem: str, mirror: bool
) -> list[tuple[Path, bool]]:
    """Write a 3D target (and its mirror) unless there already; (path, mirrored) each."""
    named = replace(target, name=stem)
    done = []
    for t in [named, mirrored3d(named)] if mirror else [named]:
        path = out / f"{t.name}.npz"
        if not (path.is_file() and path.with_suffix(".png").is_file()):
            save_volume(t, path)
        done.append((path, t is not named))
    return done


def _check_previous(index: Path, params: dict[str, Any]) -> None:
    if not index.is_file():
        return
    try:
        old = json.loads(index.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        raise DatasetError(
            f"{index} is not valid JSON; remove it or use another directory"
        ) from None
    diff = [k for k, v in params.items() if old.get(k) != v]
    if diff:
        raise DatasetError(
            f"{index.parent} holds a build with other settings "
            f"({', '.join(diff)}); use another directory"
        )


def _write_index(out: Path, meta: dict[str, Any]) -> None:
    atomic_write(out / "index.json", json.dumps(meta, indent=1) + "\n")
