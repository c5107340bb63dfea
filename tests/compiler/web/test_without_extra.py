"""Without the [web] extra, `ngpmc` imports without it and `ngpmc serve` says what to install."""

from __future__ import annotations

from pathlib import Path

from blocked_imports import run_blocked

SCRIPT = """
import contextlib, io
from ngpm_compiler.cli import main
err = io.StringIO()
with contextlib.redirect_stderr(err):
    code = main(["serve", "--port", "0"])
assert code == 1, code
assert 'needs the web extra' in err.getvalue() and '.[web]' in err.getvalue(), err.getvalue()
"""


def test_serve_without_the_web_extra_names_it(tmp_path: Path) -> None:
    proc = run_blocked(SCRIPT, tmp_path, blocked=("starlette", "uvicorn"), timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr
