"""Stops what a local Ray instance leaves running when its driver dies without cleaning up
(`kill -9`, out of memory). Ray's own processes die with the driver, but the agents that its
raylet starts (dashboard agent, runtime-env agent) linger for a minute or more.

`RayBackend` runs this file as a process of its own (`python ray_reaper.py PID...`, in a
session of its own, so signals to the driver's group do not reach it), with the pids of the
processes that `ray.init` started and a pipe from the driver on stdin. While the driver lives,
it notes every process descended from those (pid and start time, once a second); when its
stdin closes (the driver has exited, however it ended), it kills the noted ones still alive.
After a clean exit Ray has been shut down, and nothing is left to kill. Linux only (/proc);
standard library only, so it runs without importing ngpm.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from pathlib import Path

SCAN_SECONDS = 1.0


def stat(pid: int) -> tuple[int, int] | None:
    """(parent pid, start time) of a live process; None if there is none."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
        fields = text.rsplit(")", 1)[1].split()
        return (int(fields[1]), int(fields[19])) if fields[0] not in "ZX" else None
    except (OSError, IndexError, ValueError):
        return None


def processes() -> dict[int, tuple[int, int]]:
    """pid -> (parent pid, start time) of every live process."""
    out: dict[int, tuple[int, int]] = {}
    if not os.path.isdir("/proc"):
        return out
    for name in os.listdir("/proc"):
        if name.isdigit() and (st := stat(int(name))) is not None:
            out[int(name)] = st
    return out


def children(pid: int) -> set[int]:
    return {p for p, (parent, _) in processes().items() if parent == pid}


def descendants(noted: dict[int, int]) -> dict[int, int]:
    """`noted` (pid -> start time) and every live process below a noted one."""
    table = processes()
    found = dict(noted)
    grew = True
    while grew:
        grew = False
        for pid, (parent, start) in table.items():
            if pid not in found and parent in found and table[parent][1] == found[parent]:
                found[pid] = start
                grew = True
    return found


def kill(noted: dict[int, int]) -> None:
    """SIGKILL each noted process that still runs (the same one: same start time)."""
    for pid, start in noted.items():
        st = stat(pid)
        if st is not None and st[1] == start and pid != os.getpid():
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass


def main(argv: list[str]) -> None:
    noted = {int(a): st[1] for a in argv if (st := stat(int(a))) is not None}
    gone = threading.Event()

    def wait_for_eof() -> None:
        sys.stdin.buffer.read()
        gone.set()

    threading.Thread(target=wait_for_eof, daemon=True).start()
    while True:
        noted = descendants(noted)
        if gone.wait(SCAN_SECONDS):
            break
    kill(noted)


if __name__ == "__main__":
    main(sys.argv[1:])
