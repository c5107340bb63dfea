"""The compiled deriver (issue #22): a grammar's derivation loop in numba, over arrays.

`compiled_deriver(program)` writes the grammar's productions as numba source
(kernel_source.py), appends TEMPLATE (the loop of derive.Deriver.advance_all, the 2D turtle
of turtle.py and CPython's math errors), and imports the text from a cache folder under
one name per text, so numba's disk cache (keyed by the file's path) finds it in the next
process. None when the grammar needs what the loop does not do (kernel_source.Unsupported).

The loop does what the Python deriver does, in the same order and with the same float
arithmetic, so a particle draws the same primitives from the same values; the Python
deriver stays the reference the tests compare it with. What it cannot decide like Python
(an error: a math domain error, ']' without '[', a runaway grammar) raises, and the caller
runs the Python deriver instead, which raises the located error.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ngpm_runtime.geometry.kernel_source import KernelInfo, Unsupported, kernel_source
from ngpm_runtime.program import Program

# advance() outcomes per particle (derive.py's DRAWN, NEED, DONE, LIMIT) and GROW: the
# particle stopped because its stack or turtle stack is full (grow them, advance it again)
GROW = 5

HEADER = '''"""Compiled deriver of one grammar (written by ngpm_runtime.geometry.compiled)."""

import math

import numpy as np
from numba import njit

'''

TEMPLATE = '''

# ---- the generic part (ngpm_runtime.geometry.compiled.TEMPLATE) ----

_RAD = math.pi / 180.0
DRAWN, NEED, DONE, LIMIT, GROW = 1, 2, 3, 4, 5


@njit(cache=True, nogil=True)
def _check(ok, what):
    if not ok:
        raise ValueError(what)


@njit(cache=True, nogil=True)
def _sin(x):
    _check(x - x == 0.0 or x != x, "math domain error")
    return math.sin(x)


@njit(cache=True, nogil=True)
def _cos(x):
    _check(x - x == 0.0 or x != x, "math domain error")
    return math.cos(x)


@njit(cache=True, nogil=True)
def _tan(x):
    _check(x - x == 0.0 or x != x, "math domain error")
    return math.tan(x)


@njit(cache=True, nogil=True)
def _asin(x):
    _check(not (x < -1.0 or x > 1.0), "math domain error")
    return math.asin(x)


@njit(cache=True, nogil=True)
def _acos(x):
    _check(not (x < -1.0 or x > 1.0), "math domain error")
    return math.acos(x)


@njit(cache=True, nogil=True)
def _sqrt(x):
    _check(not x < 0.0, "math domain error")
    return math.sqrt(x)


@njit(cache=True, nogil=True)
def _log(x):
    _check(not x <= 0.0, "math domain error")
    return math.log(x)


@njit(cache=True, nogil=True)
def _exp(x):
    y = math.exp(x)
    _check(not (y == math.inf and x != math.inf), "math range error")
    return y


@njit(cache=True, nogil=True)
def _pow(x, y):
    _check(not (x == 0.0 and y < 0.0), "math domain error")
    _check(not (x < 0.0 and y - y == 0.0 and x - x == 0.0 and y != math.floor(y)),
           "math domain error")
    z = math.pow(x, y)
    _check(not (z - z != 0.0 and z == z and x - x == 0.0 and y - y == 0.0), "math range error")
    return z


@njit(cache=True, nogil=True)
def _floor(x):
    _check(x - x == 0.0, "cannot convert to integer")
    return np.floor(x)


@njit(cache=True, nogil=True)
def _ceil(x):
    _check(x - x == 0.0, "cannot convert to integer")
    return np.ceil(x)


@njit(cache=True, nogil=True)
def _cut(stack, sp):
    """The stack height once pending modules up to the ']' closing the branch are gone
    (derive._cut)."""
    level = 0
    j = sp - 1
    while j >= 0:
        s = int(stack[j, 0])
        if s == PUSH_SYM:
            level += 1
        elif s == POP_SYM:
            if level == 0:
                return j + 1
            level -= 1
        j -= 1
    return 0


@njit(cache=True, nogil=True)
def _check_need(need):
    """A request's prior arguments as program.prior_problem accepts them (else the Python
    deriver runs, and reports them)."""
    site = int(need[0])
    _check(0 <= site < N_SITES, "unknown site")
    k = int(need[1])
    kind = SITE_KIND[site]
    _check(kind == 3 or k == SITE_NARGS[site], "prior argument count")
    total = 0.0
    for j in range(k):
        a = need[2 + j]
        _check(a - a == 0.0, "prior arguments not finite")
        total += a
    if kind == 0:
        _check(need[3] >= 0.0, "standard deviation < 0")
    elif kind == 1:
        _check(need[2] <= need[3], "uniform a > b")
    elif kind == 2:
        _check(0.0 <= need[2] <= 1.0, "probability outside [0, 1]")
    else:
        _check(k > 0 and total > 0.0, "weights")
        for j in range(k):
            _check(need[2 + j] >= 0.0, "weights")


@njit(cache=True, nogil=True)
def _replayed(rsite, rval, rep, log, p, row, turtle, vals, nv, need):
    """Particle p's request served from a replay's recorded values (rsite, rval; rep[0]
    the next) as a round serves it: the value appended to its values, the visit logged
    (_log_visit). False when it cannot be (no value left, another site, its values or the
    log full): the round serves it (or says what is wrong)."""
    at = rep[0]
    if at >= rval.shape[0] or rsite[at] != int(need[p, 0]) or nv[p] >= vals.shape[1]:
        return False
    if not _log_visit(log, rep, p, row, turtle, need[p]):
        return False
    vals[p, nv[p]] = rval[at]
    nv[p] += 1
    need[p, 0] = -1.0
    rep[0] = at + 1
    return True


@njit(cache=True, nogil=True)
def _log_visit(log, rep, p, row, turtle, need):
    """A replayed site visit into `log` as round_kernels.pack_waiting packs one particle
    waiting at one site (rep[1]: the floats used, rep[2]: the turtle's width, rep[3]: the
    most prior arguments of a visit): False when the log is full."""
    a = int(row[2])
    k = int(need[1])
    nt = rep[2]
    at = rep[1]
    if at + 6 + nt + a + k > log.shape[0]:
        return False
    log[at] = need[0]
    log[at + 1] = 1.0
    log[at + 2] = a
    log[at + 3] = k
    log[at + 4] = p
    log[at + 5] = row[1]
    at += 6
    for q in range(nt):
        log[at + q] = turtle[q]
    at += nt
    for q in range(a):
        log[at + q] = row[3 + q]
    at += a
    for q in range(k):
        log[at + q] = need[2 + q]
    rep[1] = at + k
    if k > rep[3]:
        rep[3] = k
    return True


@njit(cache=True, nogil=True)
def advance(ids, stack, sp, turt, tst, tsp, vals, nv, need, prim, prim_par, n_prims, work,
            resume, codes, dlen, angle, max_modules, max_work, max_prims, rsite, rval, rep, log):
    """Run particles `ids` to their next resampling point (derive.Deriver.advance_all):
    codes[k] is DRAWN, NEED, DONE, LIMIT or GROW for ids[k]; a particle that drew has its
    primitive in prim (kind: 0 segment, 1 disk, 2 leaf) and prim_par; one that waits has
    (site, argument count, arguments) in need. resume[p] = (ops, drew) of a particle
    stopped by GROW, so that it goes on as if it had not stopped. Returns how many
    stopped by GROW.

    A replay (one particle) serves its requests here (_replayed): a particle waiting since
    the last step first, then each request as if the round had served it and the particle
    had been advanced again (its work counted, its module count restarted); one it cannot
    serve stops the particle as NEED. Empty rval: no replay (no particle waits)."""
    width = stack.shape[2]
    out = np.zeros((MAX_SUCC, width))
    n_stack = stack.shape[1]
    n_tst = tst.shape[1]
    n_grow = 0
    for q in range(len(ids)):
        p = ids[q]
        ops = resume[p, 0]
        drew = resume[p, 1] != 0
        resume[p, 0] = 0
        resume[p, 1] = 0
        max_ops = min(max_work - work[p], max_modules)  # this call's module budget
        stop = 0
        h = sp[p]
        st = stack[p]
        if need[p, 0] >= 0.0:  # waiting since the last step: a replay serves it first
            if not _replayed(rsite, rval, rep, log, p, st[h - 1], turt[p], vals, nv, need):
                codes[q] = NEED
                continue
        while h > 0:
            row = st[h - 1]
            ops += 1
            if ops > max_ops:
                _check(work[p] + ops <= max_work, "runaway: max work")
                stop = DRAWN if drew else LIMIT
                break
            sym = int(row[0])
            depth = int(row[1])
            n_par = int(row[2])
            code = TCODE[sym]
            kind = PRODUCES[sym]
            if kind == 1 and depth < dlen or kind == 2:
                if h - 1 + MAX_SUCC > n_stack:
                    resume[p, 0] = ops - 1
                    resume[p, 1] = 1 if drew else 0
                    stop = GROW
                    break
                r = produce(sym, row[3:], n_par, vals[p], nv[p], out, need[p])
                if r == -2:
                    _check_need(need[p])
                    if not drew and _replayed(rsite, rval, rep, log, p, row, turt[p], vals, nv,
                                              need):
                        work[p] += ops
                        ops = 0
                        max_ops = min(max_work - work[p], max_modules)  # as a new call's
                        continue
                    stop = DRAWN if drew else NEED
                    break
                nv[p] = 0
                if r >= 0:
                    h -= 1
                    for j in range(r - 1, -1, -1):
                        dst = st[h]
                        src = out[j]
                        dst[0] = src[0]
                        dst[1] = depth + 1 if kind == 1 else dlen  # 2: interpreted only
                        m = int(src[2])
                        dst[2] = m
                        for c in range(m):
                            dst[3 + c] = src[3 + c]
                        h += 1
                    continue
            if code >= 10:
                if drew and (code == 10 or code == 18 or code == 19):
                    stop = DRAWN
                    break
                made = False
                t = turt[p]
                x = t[0]
                y = t[1]
                hd = t[2]
                if code == 10 or code == 11:  # F, f
                    step = row[3] if n_par > 0 else 1.0
                    x1 = x + step * math.cos(hd * _RAD)
                    y1 = y + step * math.sin(hd * _RAD)
                    if code == 10:
                        prim[p] = 0
                        pp = prim_par[p]
                        pp[0] = x
                        pp[1] = y
                        pp[2] = x1
                        pp[3] = y1
                        pp[4] = t[3]
                        made = True
                    t[0] = x1
                    t[1] = y1
                elif code == 12:  # +
                    t[2] = hd + (row[3] if n_par > 0 else angle)
                elif code == 13:  # -
                    t[2] = hd - (row[3] if n_par > 0 else angle)
                elif code == 14:  # |
                    t[2] = hd + 180.0
                elif code == 15:  # [
                    if tsp[p] >= n_tst:
                        resume[p, 0] = ops - 1
                        resume[p, 1] = 1 if drew else 0
                        stop = GROW
                        break
                    u = tst[p, tsp[p]]
                    for c in range(4):
                        u[c] = t[c]
                    tsp[p] += 1
                elif code == 16:  # ]
                    _check(tsp[p] > 0, "turtle: ']' without a matching '['")
                    tsp[p] -= 1
                    u = tst[p, tsp[p]]
                    for c in range(4):
                        t[c] = u[c]
                elif code == 17:  # !
                    if n_par > 0:
                        t[3] = row[3]
                elif code == 18:  # ~l
                    prim[p] = 2
                    pp = prim_par[p]
                    pp[0] = x
                    pp[1] = y
                    pp[2] = hd
                    pp[3] = row[3] if n_par > 0 else 1.0
                    pp[4] = row[4] if n_par > 1 else 1.0
                    made = True
                else:  # @O
                    prim[p] = 1
                    pp = prim_par[p]
                    pp[0] = x
                    pp[1] = y
                    pp[2] = row[3] if n_par > 0 else 1.0
                    made = True
                h -= 1
                if made:
                    n_prims[p] += 1
                    _check(n_prims[p] <= max_prims, "runaway: max primitives")
                    drew = True
            elif code == 1:  # %
                h = _cut(st, h - 1)
            elif code == 2:  # halt
                h = 0
            else:
                h -= 1
        sp[p] = h
        if stop != GROW:
            work[p] += ops
        if stop:
            codes[q] = stop
            if stop == GROW:
                n_grow += 1
        else:
            codes[q] = DRAWN if drew else DONE
    return n_grow

'''


@dataclass
class CompiledDeriver:
    """A grammar's compiled derivation loop and the sizes its arrays need."""

    module: Any
    info: KernelInfo
    addresses: dict[tuple[Any, ...], int] = field(default_factory=dict)

    @property
    def advance(self) -> Any:
        return self.module.advance

    def address(self, args: tuple[Any, ...]) -> int:
        """The machine-code address of `advance` compiled for the types of `args`
        (native_call.native_address, once per process for arrays of these dtypes and
        dimensions)."""
        from ngpm_runtime.native_call import native_address

        key = tuple((a.dtype.str, a.ndim) if hasattr(a, "ndim") else type(a) for a in args)
        addr = self.addresses.get(key)
        if addr is None:
            addr = self.addresses[key] = native_address(self.advance, args)
        return addr


_LOADED: dict[str, CompiledDeriver] = {}  # by the text's digest
# by the generated module's source: None when its grammar needs the Python deriver
_BY_CODE: dict[str, CompiledDeriver | None] = {}


def cache_folder() -> Path:
    """Where the kernel modules are written: $NGPM_KERNEL_CACHE, else ~/.cache/ngpm/kernels,
    else a folder in the temporary directory."""
    env = os.environ.get("NGPM_KERNEL_CACHE")
    if env:
        return Path(env)
    home = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return home / "ngpm" / "kernels"


def compiled_deriver(program: Program, compile: bool = True) -> CompiledDeriver | None:
    """The program's compiled deriver, or None when the grammar needs the Python one (or,
    with compile=False, when it would have to be compiled: not loaded, not on disk)."""
    key = program.code
    if key in _BY_CODE:
        return _BY_CODE[key]
    try:
        source, info = kernel_source(program)
    except Unsupported:
        _BY_CODE[key] = None
        return None
    consts = f"\nMAX_SUCC = {info.max_succ}\n"
    text = HEADER + source + consts + TEMPLATE
    digest = hashlib.sha256(text.encode("utf-8")).hexdigest()[:20]
    hit = _LOADED.get(digest)
    if hit is not None:
        _BY_CODE[key] = hit
        return hit
    name = f"_ngpm_deriver_{digest}"
    if not compile and not _on_disk(name):
        return None
    try:
        path = _write(name, text)
        spec = importlib.util.spec_from_file_location(name, path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    except Exception:  # no writable cache folder, a module that does not load: Python
        _BY_CODE[key] = None
        return None
    out = _LOADED[digest] = _BY_CODE[key] = CompiledDeriver(module, info)
    return out


def forget(program: Program) -> None:
    """The program's grammar runs on the Python deriver from now on in this process (its
    kernel did not compile)."""
    _BY_CODE[program.code] = None


def _folders() -> tuple[Path, Path]:
    """Where kernel modules go: cache_folder(), else a folder in the temporary directory."""
    return cache_folder(), Path(tempfile.gettempdir()) / "ngpm-kernels"


def _on_disk(name: str) -> bool:
    """Whether numba's cache holds the compiled `advance` of kernel module `name`."""
    for folder in _folders():
        if any((folder / "__pycache__").glob(f"{name}.advance-*.nbi")):
            return True
    return False


def _write(name: str, text: str) -> Path:
    """The module's file in the cache folder (written once, atomically)."""
    for folder in _folders():
        path = folder / f"{name}.py"
        try:
            if path.is_file() and path.read_text(encoding="utf-8") == text:
                return path
            folder.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp")
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(text)
            os.replace(tmp, path)
            return path
        except OSError:
            continue
    raise OSError("no writable folder for the compiled deriver")
