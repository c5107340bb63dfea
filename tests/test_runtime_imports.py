"""The runtime must work with torch, lark and the compiler unimportable."""

import subprocess
import sys
import textwrap
from pathlib import Path

FIXTURE = Path(__file__).parent / "fixtures" / "vines_sampler.py"

SCRIPT = textwrap.dedent(
    """
    import importlib, importlib.abc, pkgutil, sys

    BLOCKED = ("torch", "lark", "ngpm_compiler")

    class Blocker(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"blocked: {name}")
            return None

    sys.meta_path.insert(0, Blocker())
    for name in BLOCKED:
        sys.modules.pop(name, None)

    import ngpm_runtime
    for info in pkgutil.iter_modules(ngpm_runtime.__path__):
        importlib.import_module("ngpm_runtime." + info.name)
    from ngpm_runtime import forward, load_program, smc, PriorProposal, SMCResult
    program = load_program(sys.argv[1])
    particle = forward(program, seed=1)
    assert particle.primitives, particle
    result = smc(program, None, 8, proposal=PriorProposal(), seed=2)
    assert isinstance(result, SMCResult)
    leaked = [m for m in sys.modules if m.split(".")[0] in BLOCKED]
    assert not leaked, leaked
    print("ok")
    """
)


def test_runtime_imports_without_torch_lark_or_compiler(tmp_path: Path) -> None:
    script = tmp_path / "check.py"
    script.write_text(SCRIPT)
    proc = subprocess.run([sys.executable, str(script), str(FIXTURE)], capture_output=True,
                          text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.strip().endswith("ok")


def test_blocker_really_blocks(tmp_path: Path) -> None:
    script = tmp_path / "check.py"
    script.write_text(SCRIPT.replace('print("ok")', "import lark"))
    proc = subprocess.run([sys.executable, str(script), str(FIXTURE)], capture_output=True,
                          text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode != 0 and "blocked: lark" in proc.stderr
