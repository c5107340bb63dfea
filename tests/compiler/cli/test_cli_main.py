"""`ngpmc`'s main: the note before a command that will compile the SMC kernels."""

import pytest
from ngpm_runtime import warmup

from ngpm_compiler import cli


@pytest.mark.parametrize(
    ("command", "cold", "noted"),
    [
        ("grow", True, True),
        ("traces", True, True),
        ("grow", False, False),
        ("compile", True, False),
    ],
)
def test_cold_kernel_note(
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    command: str,
    cold: bool,
    noted: bool,
) -> None:
    monkeypatch.setattr(warmup, "cache_is_cold", lambda: cold)
    cli._note_cold_kernels(command)
    err = capsys.readouterr().err
    assert ("compiling the SMC kernels" in err) == noted
    assert err.count("\n") == int(noted)
