"""The kernels' disk cache: a cold cache is seen, warm_up fills it, the CLI notes it."""

import os
import subprocess
import sys
from pathlib import Path

from repo_paths import REPO

CHECK = "from ngpm_runtime.warmup import cache_is_cold; print(cache_is_cold())"


def _env(cache: Path) -> dict[str, str]:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), str(REPO / "runtime")])
    return env


def _run(args: list[str], cache: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, *args], env=_env(cache), capture_output=True, text=True, timeout=600
    )


def test_warm_up_fills_an_empty_cache_and_says_so_once(tmp_path: Path) -> None:
    cache = tmp_path / "numba"
    assert _run(["-c", CHECK], cache).stdout.strip() == "True"
    first = _run(["-m", "ngpm_runtime.warmup"], cache)
    assert first.returncode == 0, first.stderr
    assert "compiling the SMC kernels" in first.stderr
    assert "kernels ready" in first.stderr
    assert any(cache.rglob("kernels.*.nbi"))
    assert _run(["-c", CHECK], cache).stdout.strip() == "False"
    again = _run(["-m", "ngpm_runtime.warmup"], cache)
    assert again.returncode == 0 and "compiling" not in again.stderr
    assert "loading the cached SMC kernels" in again.stderr
