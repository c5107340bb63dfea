"""The README's quick tour as a runnable script: its commands, read from README.md, run in a
work folder (scaled down by the tests, as written by `benchmarks/quick_tour.py`), timed."""

from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

TOUR_HEADING = "## Quick tour"
PICTURE = "my_picture"  # the tour's target picture: the demo's horse, copied


def fences(text: str) -> list[tuple[str, str]]:
    """(language, body) of every fenced block, in order."""
    out: list[tuple[str, str]] = []
    lang: str | None = None
    body: list[str] = []
    for line in text.splitlines():
        if line.startswith("```"):
            if lang is None:
                lang, body = line[3:].strip(), []
            else:
                out.append((lang, "\n".join(body) + "\n"))
                lang = None
        elif lang is not None:
            body.append(line)
    return out


def blocks(lang: str, text: str) -> list[str]:
    return [body for fence_lang, body in fences(text) if fence_lang == lang]


def commands(block: str) -> list[str]:
    """Command lines of a bash block, without comments."""
    out = []
    for line in block.splitlines():
        line = re.sub(r"\s+#.*$", "", line).strip()
        if line and not line.startswith("#"):
            out.append(line)
    return out


def tour_section(readme: str) -> str:
    start = readme.index(TOUR_HEADING)
    return readme[start : readme.index("\n## ", start + 5)]


def tour_commands(readme: str) -> list[list[str]]:
    """The tour's ngpmc commands as argument lists (without `ngpmc`)."""
    return [shlex.split(ln)[1:] for b in blocks("bash", tour_section(readme)) for ln in commands(b)]


def prepare(readme: str, work: Path) -> str:
    """Write the tour's grammar and picture into `work`; returns the grammar's file name."""
    from ngpm_runtime import bundled

    grammars = [b for b in blocks("", readme) if "endlsystem" in b]
    if len(grammars) != 1:
        raise ValueError(f"the README holds {len(grammars)} grammars, expected 1")
    found = re.search(r"Save this as `(\w+\.lsys)`", readme)
    if found is None:
        raise ValueError("the README does not say where to save its grammar")
    name = found.group(1)
    work.mkdir(parents=True, exist_ok=True)
    (work / name).write_text(grammars[0], encoding="utf-8")
    horse = bundled.demo_target_path("horse")
    shutil.copy(horse, work / f"{PICTURE}.png")
    shutil.copy(horse.with_suffix(".txt"), work / f"{PICTURE}.txt")
    return name


@dataclass
class Step:
    argv: list[str]
    seconds: float
    output: str
    code: int


def run_tour(
    readme: str, work: Path, adjust: Callable[[list[str]], list[str]] = lambda argv: argv
) -> list[Step]:
    """Run every tour command in `work`, each through `adjust` first."""
    prepare(readme, work)
    return run_commands(work, [adjust(argv) for argv in tour_commands(readme)])


def run_commands(work: Path, argvs: list[list[str]]) -> list[Step]:
    """Run ngpmc commands in-process in the folder `work`, timed; stops at the first that
    fails."""
    from ngpm_compiler.cli import main

    steps: list[Step] = []
    here = Path.cwd()
    os.chdir(work)
    try:
        for argv in argvs:
            out = io.StringIO()
            t0 = time.perf_counter()
            with contextlib.redirect_stdout(out):
                code = main(argv)
            steps.append(Step(argv, time.perf_counter() - t0, out.getvalue(), code))
            if code != 0:
                break
    finally:
        os.chdir(here)
    return steps


def similarity(output: str) -> float | None:
    """The similarity `ngpmc grow` printed, if any."""
    found = re.search(r": similarity (-?[\d.]+), ", output)
    return float(found.group(1)) if found else None
