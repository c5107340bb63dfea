"""The reaper that stops a local Ray instance's leftovers when the driver dies (tested here
without Ray; test_ray_backend.py kills a real driver)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from ngpm_compiler.jobs import ray_reaper
from ngpm_compiler.jobs.ray_backend import start_reaper, stop_reaper

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs /proc")

# a "raylet": starts an "agent" that outlives it, prints the agent's pid, then sleeps
RAYLET = (
    "import subprocess, sys, time\n"
    "agent = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(120)'])\n"
    "print(agent.pid, flush=True)\n"
    "time.sleep(120)\n"
)


def alive(pid: int) -> bool:
    return ray_reaper.stat(pid) is not None


def test_the_reaper_kills_the_orphans_once_the_driver_is_gone() -> None:
    raylet = subprocess.Popen([sys.executable, "-c", RAYLET], stdout=subprocess.PIPE, text=True)
    agent = int(raylet.stdout.readline())
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    reaper = start_reaper({raylet.pid})
    try:
        time.sleep(3 * ray_reaper.SCAN_SECONDS)  # it notes the agent while the raylet lives
        raylet.kill()  # as Ray's processes die with their driver: the agent is orphaned
        raylet.wait()
        assert alive(agent) and reaper.poll() is None
        stop_reaper(reaper)  # the driver's end of the pipe closes
        assert reaper.returncode == 0
        deadline = time.monotonic() + 10
        while alive(agent) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not alive(agent)
        assert other.poll() is None  # not one of Ray's: left alone
    finally:
        other.kill()
        other.wait()
        if alive(agent):
            os.kill(agent, signal.SIGKILL)


def test_descendants_follow_the_tree_and_pid_reuse(monkeypatch) -> None:
    table = {10: (1, 100), 11: (10, 101), 12: (11, 102), 13: (1, 103), 14: (12, 99)}
    monkeypatch.setattr(ray_reaper, "processes", lambda: table)
    assert ray_reaper.descendants({10: 100}) == {10: 100, 11: 101, 12: 102, 14: 99}
    assert ray_reaper.descendants({10: 555}) == {10: 555}  # pid 10 is now another process
