"""Fixtures that several test files share: the shipped vines program and guide, and a copy
of the demo's horse picture."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from ngpm_runtime import bundled
from ngpm_runtime.inference.guide import Guide
from ngpm_runtime.program import Program


@pytest.fixture(scope="session")
def vines() -> Program:
    """The vines program: the shipped sampler of grammars/vines.lsys (test_bundled.py keeps
    it equal to a fresh compile)."""
    return bundled.bundled_program()


@pytest.fixture(scope="session")
def vines_guide(vines: Program) -> Guide:
    """The bundled vines guide, loaded once."""
    return bundled.bundled_guide(vines)


@pytest.fixture()
def horse(tmp_path: Path) -> Path:
    """A copy of the demo horse (PNG + sidecar) in a temp folder."""
    src = bundled.demo_target_path("horse")
    shutil.copy(src, tmp_path / "horse.png")
    shutil.copy(src.with_suffix(".txt"), tmp_path / "horse.txt")
    return tmp_path / "horse.png"


@pytest.fixture(scope="session", autouse=True)
def warm_kernels() -> None:
    """Compiles and caches the SMC kernels first when the cache is cold (a fresh clone, or
    kernels just changed), so that tests reading a command's stderr line by line never see
    the one-line compile note (tests/runtime/test_warmup.py tests the note itself)."""
    from ngpm_runtime.warmup import cache_is_cold, warm_up

    if cache_is_cold():
        warm_up()
