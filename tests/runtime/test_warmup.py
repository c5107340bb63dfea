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


KERNEL = """from numba import njit


@njit(cache=True)
def f(x):
    return x + 1.0
"""


def test_a_kernel_cache_is_dropped_when_a_file_it_inlines_changes(tmp_path: Path) -> None:
    """numba checks a cached kernel against its own file only: drop_stale_cache forgets
    it when a file it depends on changes, and keeps it otherwise."""
    (tmp_path / "stalemod.py").write_text(KERNEL)
    (tmp_path / "dep.py").write_text("A = 1\n")
    script = (
        f"import sys; sys.path.insert(0, {str(tmp_path)!r}); import stalemod; "
        "from ngpm_runtime.kernel_cache import drop_stale_cache; "
        f"print(drop_stale_cache('stalemod', ('dep.py',), root={str(tmp_path)!r})); "
        "print(stalemod.f(1.0))"
    )
    cache = tmp_path / "numba"
    said = []
    for dep in ("A = 1\n", "A = 1\n", "A = 2\n", "A = 2\n"):
        (tmp_path / "dep.py").write_text(dep)
        run = _run(["-c", script], cache)
        assert run.returncode == 0, run.stderr
        said.append(run.stdout.split())
        assert any(cache.rglob("stalemod.f-*.nbi"))  # compiled and cached again
    assert said == [["False", "2.0"], ["False", "2.0"], ["True", "2.0"], ["False", "2.0"]]
