"""Without the [train] extra (no torch), the commands that train say which extra to install."""

from __future__ import annotations

from pathlib import Path

from blocked_imports import run_blocked

SCRIPT = """
import contextlib, io
from ngpm_compiler.cli import main
for argv in (["train", {traces!r}, "-o", {model!r}], ["export", {model!r}, "-o", {onnx!r}]):
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(argv)
    text = err.getvalue()
    assert code == 1, (argv, code, text)
    assert text.count("\\n") == 1 and "Traceback" not in text, text
    assert f"ngpmc {{argv[0]}} needs the train extra (torch is missing)" in text, text
    assert '.[train]' in text, text
"""


def test_train_and_export_without_torch_name_the_extra(tmp_path: Path) -> None:
    (tmp_path / "traces").mkdir()
    (tmp_path / "model.pt").write_bytes(b"not a model")
    script = SCRIPT.format(
        traces=str(tmp_path / "traces"),
        model=str(tmp_path / "model.pt"),
        onnx=str(tmp_path / "g.onnx"),
    )
    proc = run_blocked(script, tmp_path, blocked=("torch",), timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr
