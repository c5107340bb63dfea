"""3D outputs: mesh building, file writing and pictures for a plant of many segments.

    python3 benchmarks/mesh3d.py [--segments 10000] [--size 512] [--repeat 3]

Builds a random branching plant (`--segments` cylinders, a leaf on about a third of them),
then prints the best of `--repeat` wall times for: mesh_from_primitives, writing .glb, .obj
and .ply, one --size picture, and a 24-frame turntable GIF at half the size; the mesh's
vertex and triangle counts; and, when trimesh and pygltflib are installed (the [dev]
extra), their import times and installed sizes, and trimesh's own .glb export of the same
mesh for comparison. The machine may be shared: figures can be inflated.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from importlib import util
from pathlib import Path

import numpy as np
from ngpm_runtime.geometry.mesh import Mesh, mesh_from_primitives


def plant(n: int, seed: int = 0) -> list[tuple]:
    """`n` segments branching from the origin upward, with leaves (plain 3D primitives)."""
    rng = np.random.default_rng(seed)
    prims: list[tuple] = []
    tips = [(np.zeros(3), np.array([0.0, 1.0, 0.0]), 0.5)]
    segs = 0
    while segs < n:
        k = int(rng.integers(len(tips)))
        p, d, w = tips[k]
        d = d + rng.normal(0, 0.3, 3)
        d /= np.linalg.norm(d)
        q = p + 0.3 * d
        prims.append(("seg3", *p, *q, w, 0))
        segs += 1
        if rng.random() < 0.1:
            tips.append((q, d, 0.8 * w))
        if rng.random() < 0.3:
            side = np.cross(d, [0.0, 0.0, 1.0])
            side /= max(1e-9, float(np.linalg.norm(side)))
            prims.append(("leaf3", *q, *d, *side, 0.4, 0.2, 0))
        tips[k] = (q, d, 0.97 * w)
    return prims


def best(fn: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def library_rows(mesh: Mesh, out: Path, repeat: int) -> None:
    for name in ("trimesh", "pygltflib"):
        spec = util.find_spec(name)
        if spec is None or spec.origin is None:
            print(f"{name}: not installed")
            continue
        folder = Path(spec.origin).parent
        size = sum(f.stat().st_size for f in folder.rglob("*") if f.is_file())
        code = (
            f"import time; t = time.perf_counter(); import {name}; print(time.perf_counter() - t)"
        )
        took = min(
            float(
                subprocess.run(
                    [sys.executable, "-c", code], capture_output=True, text=True, check=True
                ).stdout
            )
            for _ in range(repeat)
        )
        print(f"{name}: {size / 1e6:.1f} MB installed (its own folder), import {took:.2f} s")
    if util.find_spec("trimesh") is not None:
        import trimesh

        tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
        took = best(lambda: tm.export(str(out / "trimesh.glb")), repeat)
        print(f"trimesh .glb export of the same mesh (one material): {took:.3f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--segments", type=int, default=10_000)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    prims = plant(args.segments)
    mesh = mesh_from_primitives(prims)
    print(
        f"{args.segments} segments, {len(prims) - args.segments} leaves -> "
        f"{len(mesh.vertices)} vertices, {len(mesh.faces)} triangles"
    )
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        rows = [("mesh_from_primitives", lambda: mesh_from_primitives(prims))]
        rows += [
            (f"write .{s}", lambda s=s: mesh.save(out / f"plant.{s}"))
            for s in ("glb", "obj", "ply")
        ]
        rows.append((f"picture {args.size} px", lambda: mesh.render(args.size)))
        rows.append(
            (
                f"turntable GIF, 24 frames of {args.size // 2} px",
                lambda: mesh.save(out / "t.gif", size=args.size // 2),
            )
        )
        for name, fn in rows:
            print(f"{name}: {best(fn, args.repeat):.3f} s")
        library_rows(mesh, out, args.repeat)


if __name__ == "__main__":
    main()
