"""Target datasets: the registry of sets (`DATASETS`) and `build_dataset`, which writes one.

Every family's builder (scribbles.py, varied.py, glyphs.py, silhouettes.py, clipart.py)
yields `(Target, source)` pairs; `build_dataset` writes them as `NAME_0000.png` +
`NAME_0000.txt` (the sidecar) plus `index.json`, one file at a time (atomic writes),
skipping files that already exist, so an interrupted build resumes. Nothing is downloaded:
fonts and silhouettes come from files on this machine. Contact sheets: sheets.py.
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ngpm_runtime.files import atomic_write
from ngpm_runtime.image.targets import Target, save_target, sidecar_path

from ngpm_compiler.datasets.clipart import build_clipart
from ngpm_compiler.datasets.common import DatasetError, DatasetWarning, Item
from ngpm_compiler.datasets.glyphs import build_glyphs
from ngpm_compiler.datasets.scribbles import build_scribbles
from ngpm_compiler.datasets.silhouettes import build_shapes, build_silhouettes
from ngpm_compiler.datasets.varied import build_varied


@dataclass(frozen=True)
class DatasetSpec:
    name: str
    description: str
    default_count: int | None  # None: every item the source provides
    builder: Callable[..., Iterator[Item]]


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
    "clipart": DatasetSpec(
        "clipart",
        "silhouettes of public-domain clip art (default: Openclipart animals from "
        "Debian's openclipart-svg, --from DIR for others), automatic start (testing)",
        None,
        build_clipart,
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
) -> list[Path]:
    """Build dataset `name` into out_dir; returns the PNG paths in index order.

    Existing `NAME_####.png` files with sidecars are kept as they are (resume). Source
    items that cannot be used are skipped with a DatasetWarning. With mirror=True every
    target also gets a mirrored copy `NAME_####_m.png`.
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
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    params = {
        "name": name,
        "seed": seed,
        "size": size,
        "mirror": mirror,
        "font": str(font) if font is not None else None,
        "source_dir": str(source_dir) if source_dir is not None else None,
    }
    _check_previous(out / "index.json", params)
    _write_index(out, {**params, "complete": False, "files": []})
    files: list[Path] = []
    sources: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DatasetWarning)
        for i, (target, source) in enumerate(
            spec.builder(
                count=count,
                seed=seed,
                size=size,
                font=font,
                source_dir=source_dir,
                polarity=polarity,
            )
        ):
            stem = f"{name}_{i:04d}"
            named = Target(target.mask, target.start, stem)
            versions = [named, named.mirrored()] if mirror else [named]
            for t in versions:
                path = out / f"{t.name}.png"
                if not (path.is_file() and sidecar_path(path).is_file()):
                    save_target(t, path)
                files.append(path)
                sources.append(source + (" (mirrored)" if t is not named else ""))
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
