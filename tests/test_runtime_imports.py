"""The runtime must work with torch, lark and the compiler unimportable."""

import textwrap
from pathlib import Path

from blocked_imports import run_blocked

FIXTURE = Path(__file__).parent / "fixtures" / "vines_sampler.py"

SCRIPT = textwrap.dedent(
    """
    import importlib, pkgutil

    import ngpm_runtime
    for info in pkgutil.iter_modules(ngpm_runtime.__path__):
        importlib.import_module("ngpm_runtime." + info.name)
    from ngpm_runtime import forward, load_program, smc, PriorProposal, SMCResult
    program = load_program(sys.argv[1])
    particle = forward(program, seed=1)
    assert particle.primitives, particle
    result = smc(program, None, 8, proposal=PriorProposal(), seed=2)
    assert isinstance(result, SMCResult)
    """
)


def test_runtime_imports_without_torch_lark_or_compiler(tmp_path: Path) -> None:
    proc = run_blocked(SCRIPT, tmp_path, str(FIXTURE), timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.strip().endswith("ok")


def test_blocker_really_blocks(tmp_path: Path) -> None:
    proc = run_blocked(SCRIPT + "import lark\n", tmp_path, str(FIXTURE), timeout=120)
    assert proc.returncode != 0 and "blocked: lark" in proc.stderr
