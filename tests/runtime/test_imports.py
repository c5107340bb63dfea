"""The runtime must work with torch, lark, scipy, scikit-image, matplotlib, tqdm, the mesh
libraries the tests read meshes with (trimesh, pygltflib) and the compiler unimportable."""

import textwrap
from pathlib import Path

from blocked_imports import run_blocked
from repo_paths import VINES_SAMPLER

BLOCKED = (
    "torch",
    "lark",
    "ngpm_compiler",
    "scipy",
    "skimage",
    "matplotlib",
    "tqdm",
    "trimesh",
    "pygltflib",
)

SCRIPT = textwrap.dedent(
    """
    import importlib, pkgutil

    import ngpm_runtime
    for info in pkgutil.walk_packages(ngpm_runtime.__path__, "ngpm_runtime."):
        importlib.import_module(info.name)
    from ngpm_runtime import forward, load_program, smc, PriorProposal, SMCOptions, SMCResult
    program = load_program(sys.argv[1])
    particle = forward(program, seed=1)
    assert particle.primitives, particle
    result = smc(program, None, 8, PriorProposal(), SMCOptions(seed=2))
    assert isinstance(result, SMCResult)
    from ngpm_runtime import bundled, grow
    target = bundled.demo_targets()[2]
    res = grow(bundled.bundled_program(), target, bundled.bundled_guide(), 3, seed=1)
    assert res.primitives and 0.0 <= res.similarity <= 1.0
    from ngpm_runtime import mesh_from_primitives
    mesh = mesh_from_primitives([("seg3", 0, 0, 0, 0, 1, 0, 0.1, 0), ("sphere", 0, 1, 0, 0.2, 0)])
    for suffix in ("glb", "obj", "ply", "png", "gif"):
        mesh.save(f"plant.{suffix}", size=32, frames=2)
    """
)


def test_runtime_imports_without_torch_lark_or_compiler(tmp_path: Path) -> None:
    proc = run_blocked(SCRIPT, tmp_path, str(VINES_SAMPLER), blocked=BLOCKED, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.strip().endswith("ok")


def test_blocker_really_blocks(tmp_path: Path) -> None:
    proc = run_blocked(
        SCRIPT + "import lark\n", tmp_path, str(VINES_SAMPLER), blocked=BLOCKED, timeout=120
    )
    assert proc.returncode != 0 and "blocked: lark" in proc.stderr


def test_package_grow_is_the_function_not_the_module() -> None:
    import ngpm_runtime
    import ngpm_runtime.grow
    from ngpm_runtime import grow

    assert callable(grow) and grow is ngpm_runtime.grow and grow.__module__ == "ngpm_runtime.grow"
