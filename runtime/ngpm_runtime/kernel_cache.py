"""The compiled kernels' disk cache where numba's own check does not reach.

numba checks a cached kernel against its own source file only (its modification time and
size), so a kernel that inlines functions or constants of other modules would load machine
code of their old version after an upgrade that changed only those files.
"""

from __future__ import annotations

import os
import sys


def drop_stale_cache(module: str, depends: tuple[str, ...], root: str | None = None) -> bool:
    """Forget the disk cache of `module`'s kernels when a file they call into changed (the
    module docstring; round_kernels inlines kernels.py's functions). A stamp beside the
    cache holds a digest of `depends` (paths relative to the package); when it differs, the
    module's index files are removed (numba compiles them again) and the stamp rewritten.
    `root`: the folder `depends` are in (default: this package's). True when it dropped
    anything."""
    import hashlib

    from numba.core.dispatcher import Dispatcher

    from ngpm_runtime.files import atomic_write

    package = root or os.path.dirname(os.path.abspath(__file__))
    digest = hashlib.sha256()
    for rel in depends:
        with open(os.path.join(package, rel), "rb") as f:
            digest.update(f.read())
    mod = sys.modules[module]
    own = [
        v
        for v in vars(mod).values()
        if isinstance(v, Dispatcher) and getattr(v.py_func, "__module__", None) == module
    ]
    try:
        caches = [getattr(d, "_cache") for d in own]  # noqa: B009  (numba's private cache)
        folder = caches[0]._cache_path if caches else None
        indexes = [c._cache_file._index_path for c in caches]
    except AttributeError:  # another numba's cache layout: leave it to numba
        return False
    if folder is None:
        return False
    stamp = os.path.join(folder, f"{module.rsplit('.', 1)[-1]}.ngpm-depends")
    want = digest.hexdigest()
    try:
        with open(stamp, encoding="utf-8") as f:
            if f.read() == want:
                return False
    except OSError:
        pass
    dropped = False
    for index in indexes:
        try:
            os.remove(index)
            dropped = True
        except FileNotFoundError:
            pass
        except OSError:  # a cache we may not change: numba's own check is all there is
            return False
    try:
        os.makedirs(folder, exist_ok=True)
        atomic_write(stamp, want)
    except OSError:
        pass
    return dropped
