"""`ngpmc grow` into a 3D target: a mesh (.obj, .stl, .ply, .glb), a saved target (.npz)
or a picture made 3D (--extrude, --revolve), grown by a 3D grammar (by default the bundled
vines3d with its guide); writes the best tree's mesh and a picture (target | tree)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from ngpm_runtime.errors import NgpmError
from ngpm_runtime.program import Program

from ngpm_compiler.cli import argtypes

if TYPE_CHECKING:
    from ngpm_runtime.volume.target import VolumeTarget

MESH_TARGETS = (".obj", ".stl", ".ply", ".glb", ".npz")  # files that are 3D targets
MESH_OUTPUTS = (".glb", ".obj", ".ply", ".png")
PICTURE_SIZE = 384  # each half of the --png picture


def add_arguments(p: argparse.ArgumentParser) -> None:
    """grow's options for 3D targets."""
    p.add_argument(
        "--extrude",
        type=argtypes.positive_number(4.0),
        metavar="DEPTH",
        help="3D: make the picture a slab DEPTH picture sides deep, above 0 and at most 4 "
        "(e.g. 0.25; default: not extruded)",
    )
    p.add_argument(
        "--revolve",
        action="store_true",
        help="3D: turn the picture about its vertical middle",
    )
    p.add_argument(
        "--resolution",
        type=argtypes.integer(4, 256),
        default=32,
        help="3D: voxels a side of the target grid (default 32, 4 to 256)",
    )
    p.add_argument(
        "--png",
        type=argtypes.path,
        metavar="PATH",
        help="3D: also write a picture, the target's voxels beside the grown tree (default: none)",
    )


def wants_3d(args: argparse.Namespace, image: str | None, program: Program | None) -> bool:
    """Whether this grow is 3D: a 3D grammar, a mesh or .npz target, or --extrude/--revolve."""
    if program is not None and program.dim == 3:
        return True
    if args.extrude is not None or args.revolve or args.png is not None:
        return True
    return image is not None and Path(image).suffix.lower() in MESH_TARGETS


def _outputs(args: argparse.Namespace, image: str) -> tuple[Path, Path | None]:
    """(mesh or picture, side-by-side picture) paths, checked before any work is done."""
    from ngpm_compiler.cli.outpaths import check_output_file

    if args.svg is not None or args.steps_gif is not None:
        raise NgpmError("--svg and --steps-gif draw 2D vines; a 3D grow writes -o and --png")
    out = Path(args.out) if args.out else Path(f"{Path(image).stem}_grown.glb")
    if out.suffix.lower() not in MESH_OUTPUTS:
        raise NgpmError(f"{out}: a 3D grow writes {', '.join(MESH_OUTPUTS)} (-o)")
    png = Path(args.png) if args.png else None
    if png is not None and png.suffix.lower() != ".png":
        raise NgpmError(f"{png}: --png writes a .png file")
    for path in (out, png):
        if path is not None:
            check_output_file(path)
    return out, png


def _program(program: Program | None, image: str, args: argparse.Namespace) -> Program:
    """The grammar to grow: the given 3D one, else the bundled vines3d."""
    from ngpm_runtime import bundled

    if program is None:
        return bundled.bundled_program3d()
    if program.dim != 3:
        if Path(image).suffix.lower() in MESH_TARGETS:
            why = f"{image} is a 3D target"
        elif args.extrude is not None:  # a picture made 3D by an option only 3D grows have
            why = "--extrude makes a 3D grow"
        elif args.revolve:
            why = "--revolve makes a 3D grow"
        else:
            why = "--png makes a 3D grow (a 2D grow writes its picture with -o)"
        raise NgpmError(
            f"{why}, and {program.name} is a 2D grammar: give a 3D grammar "
            "(or none: the bundled vines3d)"
        )
    return program


def _target(args: argparse.Namespace, image: str, program: Program) -> VolumeTarget:
    from ngpm_runtime.volume.load import load_volume_target

    if args.extrude is not None and args.revolve:
        raise NgpmError("give --extrude or --revolve, not both")
    return load_volume_target(
        image, program, resolution=args.resolution, extrude=args.extrude, revolve=args.revolve
    )


def cmd_grow3d(args: argparse.Namespace, image: str | None, program: Program | None) -> int:
    """grow a 3D grammar into a 3D target; prints the similarity, writes the files."""
    from ngpm_compiler.cli.grow_common import (
        LOW_SIMILARITY,
        SIMILARITY_SCALE,
        _grow_guide,
        _step_ticks,
    )
    from ngpm_compiler.progress import Progress

    if image is None:
        raise NgpmError("give a 3D target: ngpmc grow shape.obj -o tree.glb")
    if args.likelihood != "shape":
        raise NgpmError("a 3D grammar grows with the shape likelihood only")
    out, png = _outputs(args, image)
    program = _program(program, image, args)
    target = _target(args, image, program)
    guide = _grow_guide(args.guide, program, "shape")
    from ngpm_runtime.grow import grow

    with Progress("grow", unit="step", delay=1.0, leave=False) as bar:
        res = grow(
            program,
            target,
            guide,
            args.particles,
            args.seed,
            observers=(_step_ticks(bar),),
            max_modules=args.max_modules,
        )
    kind = "guided" if guide else "unguided"
    print(
        f"{target.name}: similarity {res.similarity:.3f}, {res.particles} particles ({kind}), "
        f"{res.seconds:.2f} s, {len(res.primitives)} primitives, "
        f"{target.resolution}^3 voxels"
    )
    if res.similarity < LOW_SIMILARITY:
        print(f"similarity: {SIMILARITY_SCALE}")
    if guide is not None:
        print(f"guide: {guide.path}")
    _save(res.primitives, target, out, png)
    return 0


def _save(prims: list, target: VolumeTarget, out: Path, png: Path | None) -> None:
    """The tree's mesh (or picture) to `out`; the target beside the tree to `png`."""
    from ngpm_runtime.geometry.mesh import mesh_from_primitives
    from ngpm_runtime.image.render3d import render_side_by_side, save_png

    mesh = mesh_from_primitives(prims)
    mesh.save(out)
    print(f"wrote {out} ({len(mesh.faces)} triangles)")
    if png is not None:
        save_png(render_side_by_side([target.mesh(), mesh], PICTURE_SIZE), png)
        print(f"wrote {png} (target | grown tree)")
