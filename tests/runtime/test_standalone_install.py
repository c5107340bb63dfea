"""`pip install ./runtime` in a fresh virtual environment (no system site-packages) gives a
runtime that grows a vine, samples a 3D grammar's compiled module (plant3d) and writes its
mesh and pictures without lark, torch, matplotlib, scipy, scikit-image or a mesh library."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
import venv
from pathlib import Path

import pytest
from repo_paths import REPO

SCRIPT = textwrap.dedent(
    """
    import importlib.util, sys
    from ngpm_runtime import grow
    from ngpm_runtime import bundled

    import ngpm_runtime
    assert "site-packages" in ngpm_runtime.__file__, ngpm_runtime.__file__
    target = bundled.demo_targets()[1]
    res = grow(bundled.bundled_program(), target, bundled.bundled_guide(), 3, seed=0)
    assert res.primitives and 0.0 <= res.similarity <= 1.0, res
    from ngpm_runtime import mesh_from_primitives
    from ngpm_runtime.inference.smc import forward
    from ngpm_runtime.program import load_program
    plant = load_program(sys.argv[1])  # a 3D grammar's module, compiled by the test
    assert plant.dim == 3, plant.dim
    prims = forward(plant, seed=0).primitives
    assert len(prims) > 100 and {p[0] for p in prims} >= {"seg3", "poly3"}, len(prims)
    mesh = mesh_from_primitives(prims)
    for suffix, least in (("glb", 100_000), ("obj", 100_000), ("ply", 100_000), ("png", 100)):
        assert mesh.save(f"plant.{suffix}", size=32).stat().st_size > least, suffix
    assert open("plant.glb", "rb").read(4) == b"glTF"
    missing = [m for m in ("lark", "torch", "matplotlib", "scipy", "skimage", "tqdm",
                           "trimesh", "pygltflib", "ngpm_compiler")
               if importlib.util.find_spec(m) is not None]
    assert not missing, missing
    print("grown", target.name, len(res.primitives), round(res.similarity, 3))
    """
)


@pytest.mark.slow
def test_runtime_installs_and_grows_alone(tmp_path: Path) -> None:
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True, system_site_packages=False).create(env_dir)
    python = env_dir / ("Scripts" if os.name == "nt" else "bin") / "python"
    src = tmp_path / "runtime"  # a copy, so the build leaves no files in the repository
    shutil.copytree(
        REPO / "runtime", src, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info", "build")
    )
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    pip = subprocess.run(
        [str(python), "-m", "pip", "install", "-q", "--disable-pip-version-check", str(src)],
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
    )
    assert pip.returncode == 0, pip.stdout[-2000:] + pip.stderr[-3000:]
    from ngpm_compiler.language.compile import compile_grammar, write_compiled

    sampler, _ = write_compiled(compile_grammar(REPO / "grammars" / "plant3d.lsys"), tmp_path)
    run = subprocess.run(
        [str(python), "-c", SCRIPT, str(sampler)],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.startswith("grown horse"), run.stdout
    assert sys.executable != str(python)
