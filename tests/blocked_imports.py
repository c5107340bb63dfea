"""Run a Python script in a subprocess in which some top-level packages cannot be imported."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

PRELUDE = """
import importlib.abc, sys

BLOCKED = {blocked!r}

class Blocker(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"blocked: {{name}}", name=name)
        return None

sys.meta_path.insert(0, Blocker())
for _name in BLOCKED:
    sys.modules.pop(_name, None)
"""

EPILOGUE = """
leaked = [m for m in sys.modules if m.split(".")[0] in BLOCKED]
assert not leaked, leaked
print("ok")
"""


def run_blocked(
    body: str,
    tmp_path: Path,
    *args: str,
    blocked: tuple[str, ...] = ("torch", "lark", "ngpm_compiler"),
    timeout: int = 300,
) -> subprocess.CompletedProcess:
    """Run `body` with `blocked` unimportable; it prints "ok" at the end if none leaked in."""
    script = tmp_path / "blocked_check.py"
    script.write_text(PRELUDE.format(blocked=tuple(blocked)) + body + EPILOGUE)
    return subprocess.run(
        [sys.executable, str(script), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=tmp_path,
    )
