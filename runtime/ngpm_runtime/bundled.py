"""Package data: the vines model, its pretrained guide and the demo targets; the 3D
vines3d model and its guide (the default of `ngpmc grow shape.obj`).

Everything lives in `ngpm_runtime/data/` (`runtime/ngpm_runtime/data/` in the repository):

- `vines_sampler.py`, `vines_sites.json`:
  `ngpmc compile grammars/vines.lsys -o runtime/ngpm_runtime/data`
- `vines_guide.onnx`: `bash scripts/train_vines_guide.sh work/vines`, then copied here
- `vines_circuit_guide.onnx` (the vines guide for the circuit likelihood):
  `bash scripts/train_circuit_guide.sh work/circuit` (`ngpmc learn --likelihood circuit`),
  then `work/circuit/guide.onnx` copied here
- `vines3d_sampler.py`, `vines3d_sites.json`:
  `ngpmc compile grammars/vines3d.lsys -o runtime/ngpm_runtime/data`
- `vines3d_guide.onnx`: `bash scripts/train_vines3d_guide.sh work/vines3d`
  (`ngpmc learn grammars/vines3d.lsys`), then `work/vines3d/guide.onnx` copied here
- `demo_<name>.png` + `demo_<name>.txt`: the demo's targets (image + start sidecar), and
  `demo_vase.obj`, the mesh of its 3D rows, made by
  `ngpm_compiler.datasets.demo_targets.write_demo_targets("runtime/ngpm_runtime/data")`

Only numpy / onnxruntime code is imported here: no torch, no lark, no compiler.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

from ngpm_runtime.errors import GuideError, ProgramError, TargetError
from ngpm_runtime.program import Program, load_program

if TYPE_CHECKING:  # imported on first use: onnxruntime and PIL load only then
    from ngpm_runtime.image.targets import Target
    from ngpm_runtime.inference.guide import Guide

DATA_DIR = Path(__file__).resolve().parent / "data"
SAMPLER_FILE = "vines_sampler.py"
SITES_FILE = "vines_sites.json"
GUIDE_FILE = "vines_guide.onnx"
CIRCUIT_GUIDE_FILE = "vines_circuit_guide.onnx"
DEMO_TARGETS = ("glyph", "horse", "heart", "spiral")  # demo order
REGENERATE = "bash scripts/train_vines_guide.sh work/vines"
REGENERATE_CIRCUIT = "bash scripts/train_circuit_guide.sh work/circuit"
SAMPLER_3D = "vines3d_sampler.py"
GUIDE_3D = "vines3d_guide.onnx"
REGENERATE_3D = "bash scripts/train_vines3d_guide.sh work/vines3d"


def data_path(name: str) -> Path:
    """Path of a file in the package's data folder (it may not exist)."""
    return DATA_DIR / name


def sampler_path() -> Path:
    return data_path(SAMPLER_FILE)


def guide_path() -> Path:
    return data_path(GUIDE_FILE)


def demo_target_path(name: str) -> Path:
    """The PNG of a built-in demo target (`glyph`, `horse`, `heart`, `spiral`)."""
    if name not in DEMO_TARGETS:
        raise TargetError(
            f"no built-in demo target {name!r}; choose from {', '.join(DEMO_TARGETS)}"
        )
    return data_path(f"demo_{name}.png")


@lru_cache(maxsize=1)
def _cached_program(path: str, mtime: float) -> Program:
    return load_program(path)


def bundled_program() -> Program:
    """The vines Program from the generated sampler shipped with the package."""
    path = sampler_path()
    if not path.is_file():
        raise ProgramError(
            f"{path}: the bundled vines sampler is missing "
            "(regenerate: ngpmc compile grammars/vines.lsys "
            "-o runtime/ngpm_runtime/data)"
        )
    return _cached_program(str(path), path.stat().st_mtime)


def bundled_program3d() -> Program:
    """The 3D vines3d Program from the generated sampler shipped with the package."""
    path = data_path(SAMPLER_3D)
    if not path.is_file():
        raise ProgramError(
            f"{path}: the bundled 3D sampler is missing "
            "(regenerate: ngpmc compile grammars/vines3d.lsys "
            "-o runtime/ngpm_runtime/data)"
        )
    return _cached_program(str(path), path.stat().st_mtime)


def bundled_guide3d(program: Program | None = None) -> Guide:
    """The pretrained vines3d guide for `program` (default: bundled_program3d())."""
    from ngpm_runtime.inference.guide import Guide

    path = data_path(GUIDE_3D)
    if not path.is_file():
        raise GuideError(
            f"{path}: the bundled 3D guide is missing (regenerate it with "
            f"`{REGENERATE_3D}` and copy work/vines3d/guide.onnx there as {GUIDE_3D})"
        )
    return Guide.load(path, bundled_program3d() if program is None else program)


def bundled_guide(program: Program | None = None, likelihood: str = "shape") -> Guide:
    """The pretrained vines guide (a `ngpm_runtime.inference.guide.Guide`) for `program`,
    trained for `likelihood` ("shape", or "circuit": the circuit guide).

    `program` defaults to `bundled_program()`; any Program compiled from the same
    grammars/vines.lsys works (the guide checks the grammar hash and the site table).
    """
    from ngpm_runtime.inference.guide import Guide

    name, how = LIKELIHOOD_GUIDES[likelihood]
    path = data_path(name)
    if not path.is_file():
        what = "guide" if likelihood == "shape" else f"{likelihood} guide"
        raise GuideError(
            f"{path}: the bundled vines {what} is missing "
            f"(regenerate it with `{how}` and copy "
            f"{how.split()[-1]}/{name} there)"
        )
    return Guide.load(path, bundled_program() if program is None else program)


# the bundled vines guide of each likelihood (a guide is trained for one likelihood) and
# the command that makes it
LIKELIHOOD_GUIDES = {
    "shape": (GUIDE_FILE, REGENERATE),
    "circuit": (CIRCUIT_GUIDE_FILE, REGENERATE_CIRCUIT),
}


def default_guide(program: Program, likelihood: str = "shape") -> Guide | None:
    """The bundled guide for `program` under `likelihood`, or None when none is bundled
    (another grammar, or a likelihood with no trained guide: unguided SMC, never a guide
    trained for another likelihood)."""
    if likelihood not in LIKELIHOOD_GUIDES:
        return None
    if program.dim == 3:
        if likelihood != "shape":
            return None
        if program.grammar_hash != bundled_program3d().grammar_hash:
            return None
        return bundled_guide3d(program)
    if program.grammar_hash != bundled_program().grammar_hash:
        return None
    return bundled_guide(program, likelihood)


def demo_targets(size: int = 50) -> list[Target]:
    """The built-in demo targets (`ngpm_runtime.image.targets.Target`), in DEMO_TARGETS order."""
    from ngpm_runtime.image.targets import Target, load_target

    targets = []
    for name in DEMO_TARGETS:
        path = demo_target_path(name)
        if not path.is_file():
            raise TargetError(f"{path}: built-in demo target is missing")
        t = load_target(path, size=size)
        targets.append(Target(t.mask, t.start, name))
    return targets


def guide_summary(guide: Guide) -> str:
    """One line on how a guide was trained, from its ONNX metadata."""
    t = guide.training or {}
    parts = [f"{len(guide.nets)} site networks", f"features {guide.feature_set}", f"K {guide.K}"]
    if t.get("traces") is not None:
        parts.append(f"{t['traces']} traces ({t.get('val_traces', 0)} held out)")
    if t.get("best_epoch") is not None:
        parts.append(f"best epoch {t['best_epoch']} of {t.get('epochs_run', '?')}")
    if isinstance(t.get("val_nll"), (int, float)):
        parts.append(f"validation NLL {t['val_nll']:.3f} per trace")
    settings = getattr(guide, "settings", None)
    if settings is not None and settings != type(settings)():
        parts.append(f"proposes with {settings.label()} (ngpmc tune)")
    return ", ".join(parts)
