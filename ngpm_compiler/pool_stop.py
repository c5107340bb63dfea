"""Stop a multiprocessing pool without hanging.

`Pool.terminate()` first takes the task queue's lock; a worker killed while holding it
(`timeout 60 ngpmc traces ...` sends SIGTERM to the whole process group) never gives it
back, and terminate() then waits forever. Here terminate() runs in a daemon thread; if it
has not finished in `grace` seconds, the workers are killed and the command goes on (its
manifest is written, it exits), leaving that thread behind."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

GRACE_SECONDS = 3.0


def stop_pool(pool: Any, grace: float = GRACE_SECONDS) -> bool:
    """Terminate `pool`; True if its own terminate() finished, False if it had to be left."""
    stopper = threading.Thread(target=pool.terminate, name="pool-stop", daemon=True)
    stopper.start()
    stopper.join(grace)
    if not stopper.is_alive():
        return True
    for proc in list(getattr(pool, "_pool", None) or []):  # the worker processes
        try:
            proc.kill()
            proc.join(1.0)
        except (OSError, ValueError, AttributeError):
            pass
    stopper.join(1.0)
    return not stopper.is_alive()


@contextmanager
def stopping(pool: Any, grace: float = GRACE_SECONDS) -> Iterator[Any]:
    """`with stopping(ctx.Pool(...)) as pool:` like `with ctx.Pool(...)`, but never hangs
    on the way out."""
    try:
        yield pool
    finally:
        stop_pool(pool, grace)
