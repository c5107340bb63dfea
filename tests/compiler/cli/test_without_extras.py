"""A plain `pip install .` has no scipy, scikit-image or matplotlib: every ngpm_compiler
module imports without them, `ngpmc --help` works, and a command that needs one names the
extra that installs it (training targets need none of them)."""

from __future__ import annotations

from pathlib import Path

from blocked_imports import run_blocked

EXTRA_PACKAGES = ("scipy", "skimage", "matplotlib")

IMPORTS = """
import contextlib, importlib, io, pkgutil
import ngpm_compiler
for info in pkgutil.walk_packages(ngpm_compiler.__path__, "ngpm_compiler."):
    if not info.name.endswith(".__main__"):  # that one runs ngpmc
        importlib.import_module(info.name)
from ngpm_compiler.cli import main
out = io.StringIO()
with contextlib.redirect_stdout(out):
    try:
        main(["--help"])
    except SystemExit as err:
        assert err.code == 0, err.code
assert "usage: ngpmc" in out.getvalue(), out.getvalue()
"""

MISSING = """
import contextlib, io
from ngpm_compiler.cli import main
for name, package, extra in (("silhouettes", "skimage", "eval"),
                             ("glyphs", "matplotlib", "train")):
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(["targets", "build", name, "-o", sys.argv[1] + "/" + name, "--count", "2"])
    text = err.getvalue()
    assert code == 1, (name, code, text)
    assert text.count("\\n") == 1 and "Traceback" not in text, text
    assert f"ngpmc targets needs the {extra} extra ({package} is missing)" in text, text
assert main(["targets", "build", "scribbles", "-o", sys.argv[1] + "/s", "--count", "2"]) == 0
"""


def test_compiler_and_help_need_no_eval_packages(tmp_path: Path) -> None:
    proc = run_blocked(IMPORTS, tmp_path, blocked=EXTRA_PACKAGES, timeout=300)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr[-3000:]


def test_targets_name_the_missing_extra(tmp_path: Path) -> None:
    proc = run_blocked(MISSING, tmp_path, str(tmp_path), blocked=EXTRA_PACKAGES, timeout=300)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr[-3000:]
