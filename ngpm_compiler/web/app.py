"""The `ngpmc serve` application: sketch a shape in the browser, watch SMC grow a vine into it.

Routes (every error is JSON `{"error": "..."}` with a fitting status code):

- `GET /`: the page (static/index.html); sets the client-id cookie.
- `GET /api/options`: the grammars and guides on offer and the limits.
- `POST /api/grow` (JSON: image data URL, grammar, guide, particles, seed, start, polarity):
  validates everything, then answers a `text/event-stream`: one `target` event (the mask the
  model sees, the start, the viewport), `frame` events while SMC runs (the primitives of the
  best partial vine: `append` to the last frame or `reset`), then `done` (similarity,
  seconds, the final primitives, PNG and SVG data URLs) or `error`.
- `POST /api/shape` (JSON: image data URL): the shape found in an uploaded picture, as a
  PNG mask the page paints onto its canvas.
- `GET /api/examples`, `GET /api/examples/{name}`: the demo's pictures as masks + starts.

Pictures are decoded by the runtime's one loader (`ngpm_runtime.image.targets.read_image`,
as `ngpmc grow` does: size checked from the header first, an animation's first frame that
holds a shape), at most `Limits.max_runs` at once. SMC runs in a worker thread, one run per
client address (not per anything the client declares) and at most `Limits.max_runs` at
once; a run stops at its time limit or when its client goes away (checked at every SMC
step through `grow(..., observers=...)`). A request's JSON is bounded in size, depth and
count of values; its line, headers and body must arrive within `Limits.request_timeout_s`
(`DeadlineProtocol`), and uvicorn answers 503 beyond `Limits.max_connections`.
"""

from __future__ import annotations

import asyncio
import base64
import binascii
import io
import json
import logging
import math
import re
import socket
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from ngpm_runtime.errors import GuideError, NgpmError, TargetError
from ngpm_runtime.inference.smc import SMCObserver, SMCState
from ngpm_runtime.program import Program
from PIL import Image
from starlette.applications import Starlette
from starlette.exceptions import HTTPException
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import ClientDisconnect, Request
from starlette.responses import FileResponse, JSONResponse, Response, StreamingResponse
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles
from starlette.types import Receive, Scope, Send

log = logging.getLogger("ngpmc.serve")

STATIC_DIR = Path(__file__).resolve().parent / "static"
DATA_URL_RE = re.compile(r"^data:([\w.+/-]*)((?:;[\w.+-]+=[\w.+-]+)*)(;base64)?,", re.ASCII)
NOT_BRACKETS = bytes(c for c in range(256) if c not in b"[]{}")  # bytes.translate deletes
MAX_JSON_DEPTH = 8  # nested [ ] and { } in a request (the API needs 2)
MAX_JSON_VALUES = 256  # values and containers in a request (the API needs about 12)
POLARITIES = ("auto", "dark", "light", "alpha")
GROW_KEYS = ("image", "grammar", "guide", "particles", "seed", "start", "polarity")
SHAPE_SIZE = 256  # side of the masks /api/shape and /api/examples return
RENDER_SIZE = 512  # side of the PNG and SVG downloads
MASK_RGBA = (150, 168, 200, 255)  # the target as the page shows it (a light blue-gray)
HOSTS = ("127.0.0.1", "localhost", "[::1]")


# --------------------------------------------------------------------------- configuration


@dataclass(frozen=True)
class Limits:
    """What the server accepts; the page reads them from /api/options."""

    max_body_bytes: int = 12 * 2**20  # a JSON request (the image travels as base64)
    max_image_bytes: int = 8 * 2**20  # the decoded image file
    max_side: int = 4096  # pixels, each side of the image
    max_particles: int = 500
    default_particles: int = 10
    timeout_s: float = 60.0  # per run
    max_runs: int = 2  # runs at once, over all clients; also pictures decoded at once
    target_size: int = 50  # the model's target resolution (as `ngpmc grow --size`)
    request_timeout_s: float = 10.0  # a request's line, headers and body must arrive in it
    max_connections: int = 32  # uvicorn's limit_concurrency: beyond it requests get 503


@dataclass
class GuideChoice:
    id: str
    name: str
    guide: Any  # ngpm_runtime.inference.guide.Guide


@dataclass
class GrammarChoice:
    id: str
    name: str
    source: str  # "bundled" or "command line"
    program: Program
    guides: list[GuideChoice] = field(default_factory=list)


@dataclass
class WebConfig:
    grammars: list[GrammarChoice]
    limits: Limits = field(default_factory=Limits)

    def grammar(self, gid: str) -> GrammarChoice | None:
        return next((g for g in self.grammars if g.id == gid), None)


def _load_grammar(path: str) -> Program:
    from ngpm_compiler.language.compile import load_grammar

    if not Path(path).is_file():
        raise NgpmError(f"{path}: no such grammar file")
    return load_grammar(path)


def load_config(grammar: str | None = None, guide: str | None = None,
                limits: Limits | None = None) -> WebConfig:
    """The bundled vines model and guide, plus the grammar and guide of the command line
    (`--guide` alone is a guide for the bundled vines; `--guide none`: offer no guide)."""
    from ngpm_runtime import bundled
    from ngpm_runtime.inference.guide import Guide

    vines = GrammarChoice("vines", "vines", "bundled", bundled.bundled_program())
    try:
        vines.guides.append(GuideChoice("bundled", "bundled vines guide",
                                        bundled.bundled_guide(vines.program)))
    except GuideError as err:  # a checkout without the guide file: unguided only
        log.warning("%s", err)
    choices = [vines]
    no_guide = guide is not None and guide.lower() == "none"
    if grammar is None:
        if guide is not None and not no_guide:
            vines.guides.insert(0, GuideChoice("cli", Path(guide).name,
                                               Guide.load(guide, vines.program)))
        elif no_guide:
            vines.guides.clear()
        return WebConfig(choices, limits or Limits())
    program = _load_grammar(grammar)
    mine = GrammarChoice("cli", f"{program.name or Path(grammar).stem} ({Path(grammar).name})",
                         "command line", program)
    if program.viewport is None:
        raise NgpmError(f"grammar {grammar} has no viewport: cannot grow into a picture")
    if guide is not None and not no_guide:
        mine.guides.append(GuideChoice("cli", Path(guide).name, Guide.load(guide, program)))
    elif not no_guide and program.grammar_hash == vines.program.grammar_hash:
        mine.guides = list(vines.guides)
    return WebConfig([mine, *choices], limits or Limits())


# --------------------------------------------------------------------------- errors


class ApiError(Exception):
    """An error answered as JSON `{"error": message}` with `status`."""

    def __init__(self, status: int, message: str, headers: dict[str, str] | None = None):
        super().__init__(message)
        self.status = status
        self.message = message
        self.headers = headers


def _error(status: int, message: str, headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status, headers=headers)


async def _api_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, ApiError)
    return _error(exc.status, exc.message, exc.headers)


async def _http_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, HTTPException)
    messages = {404: f"no such page: {request.url.path}",
                405: f"{request.method} is not allowed on {request.url.path}"}
    return _error(exc.status_code, messages.get(exc.status_code, str(exc.detail)),
                  dict(exc.headers) if exc.headers else None)


async def _server_error(request: Request, exc: Exception) -> Response:
    log.error("internal error on %s %s", request.method, request.url.path, exc_info=exc)
    return _error(500, f"internal error ({type(exc).__name__}); the server log has details")


# --------------------------------------------------------------------------- input checks


async def read_json(request: Request, limit: int) -> dict[str, Any]:
    """The request's JSON object, read with a cap on its size, depth and count of values."""
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype != "application/json":
        raise ApiError(415, "send the request as JSON (Content-Type: application/json)")
    too_big = f"the request is larger than {_mib(limit)}"
    length = request.headers.get("content-length")
    if length is not None and length.isdigit() and int(length) > limit:
        raise ApiError(413, too_big)
    body = bytearray()
    try:
        async for chunk in request.stream():
            body += chunk
            if len(body) > limit:
                raise ApiError(413, too_big)
    except ClientDisconnect:  # gone, or cut off by the request deadline
        raise ApiError(400, "the request body did not arrive (in time)") from None
    check_json_shape(bytes(body))
    try:
        data = json.loads(bytes(body))
    except (ValueError, UnicodeDecodeError, RecursionError):
        raise ApiError(400, "the request body is not valid JSON") from None
    if not isinstance(data, dict):
        raise ApiError(400, "the request body must be a JSON object")
    return data


def check_json_shape(body: bytes) -> None:
    """Refuse JSON with more than MAX_JSON_VALUES values or nested deeper than
    MAX_JSON_DEPTH, before parsing it: deep nesting overflows the parser's stack, and many
    small values take far more memory than their bytes. A few passes at C speed: escapes
    dropped, strings cut out, then the brackets counted (at most 2 * MAX_JSON_VALUES + 1)."""
    plain = body.replace(b"\\\\", b"").replace(b'\\"', b"")  # now every quote is a delimiter
    too_many = ApiError(400, f"the request body holds too many values (more than "
                             f"{MAX_JSON_VALUES})")
    if plain.count(b'"') > 2 * MAX_JSON_VALUES:
        raise too_many
    outside = b"".join(plain.split(b'"')[::2])  # the text outside strings
    if sum(outside.count(c) for c in (b"[", b"{", b",")) > MAX_JSON_VALUES:
        raise too_many
    depth = 0
    for byte in outside.translate(None, NOT_BRACKETS):
        depth += 1 if byte in b"[{" else -1
        if depth > MAX_JSON_DEPTH:
            raise ApiError(400, f"the request body is nested too deeply (more than "
                                f"{MAX_JSON_DEPTH} levels of [ ] and {{ }})")
        if depth < 0:  # unbalanced: the parser will say it is not JSON
            return


def _mib(n: int) -> str:
    return f"{n / 2**20:g} MiB"


def decode_image(value: Any, limits: Limits) -> Image.Image:
    """A PIL image from a data URL (or bare base64), through the runtime's one loader:
    format and size checked from the header before any pixel is decoded."""
    from ngpm_runtime.image.targets import (
        ImageDecodeError,
        ImageFormatError,
        ImageSizeError,
        read_image,
    )

    if not isinstance(value, str) or not value:
        raise ApiError(400, "'image' must be an image as a data URL "
                            "(data:image/png;base64,...)")
    m = DATA_URL_RE.match(value)
    if value.startswith("data:"):
        if m is None or not m.group(3):
            raise ApiError(400, "'image' must be a base64 data URL (data:image/png;base64,...)")
        value = value[m.end():]
    if len(value) * 3 // 4 > limits.max_image_bytes + 3:
        raise ApiError(413, f"the image file is larger than {_mib(limits.max_image_bytes)}")
    try:
        raw = base64.b64decode(value, validate=True)
    except (binascii.Error, ValueError):
        raise ApiError(400, "'image' is not valid base64") from None
    try:
        return read_image(io.BytesIO(raw), "the picture", max_side=limits.max_side,
                          max_pixels=limits.max_side ** 2)
    except ImageFormatError as err:
        raise ApiError(415, str(err)) from None
    except ImageSizeError as err:
        raise ApiError(413, str(err)) from None
    except ImageDecodeError as err:
        raise ApiError(400, str(err)) from None
    except TargetError as err:  # an animation without a frame that holds a shape
        raise ApiError(422, _target_message(err)) from None


def _int(body: dict[str, Any], key: str, default: int, lo: int, hi: int) -> int:
    value = body.get(key, default)
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ApiError(400, f"'{key}' must be a whole number from {lo} to {hi}")
    if not lo <= value <= hi:
        raise ApiError(400, f"'{key}' must be from {lo} to {hi}, got {value}")
    return value


def parse_start(value: Any) -> tuple[float, float, float, float] | None:
    """None (automatic) or (x, y, dx, dy): a point in [0, 1] from the top-left corner of the
    picture and a direction in image axes (y down)."""
    if value is None or value == "auto":
        return None
    if isinstance(value, dict):
        unknown = set(value) - {"x", "y", "dx", "dy"}
        if unknown or len(value) != 4:
            raise ApiError(400, "'start' must be null or {x, y, dx, dy}")
        value = [value["x"], value["y"], value["dx"], value["dy"]]
    if not isinstance(value, list | tuple) or len(value) != 4 or any(
            isinstance(v, bool) or not isinstance(v, int | float) for v in value):
        raise ApiError(400, "'start' must be null or {x, y, dx, dy} (four numbers)")
    x, y, dx, dy = (float(v) for v in value)
    if not all(math.isfinite(v) for v in (x, y, dx, dy)):
        raise ApiError(400, "'start' has a value that is not a finite number")
    if not (0.0 <= x <= 1.0 and 0.0 <= y <= 1.0):
        raise ApiError(400, f"the start point ({x:g}, {y:g}) must lie in [0, 1] x [0, 1]")
    norm = math.hypot(dx, dy)
    if norm < 1e-9:
        raise ApiError(400, "the start direction (dx, dy) must not be zero")
    return x, y, dx / norm, dy / norm


def _polarity(body: dict[str, Any]) -> str:
    value = body.get("polarity", "auto")
    if value not in POLARITIES:
        raise ApiError(400, f"'polarity' must be one of {', '.join(POLARITIES)}")
    return str(value)


@dataclass
class Job:
    grammar: GrammarChoice
    guide: GuideChoice | None
    target: Any  # ngpm_runtime.image.targets.Target
    particles: int
    seed: int


def parse_grow(body: dict[str, Any], config: WebConfig) -> Job:
    """A validated job from a /api/grow request, or an ApiError saying what is wrong."""
    from ngpm_runtime.image.targets import Target, auto_start, mask_from_image

    unknown = sorted(set(body) - set(GROW_KEYS))
    if unknown:
        raise ApiError(400, f"unknown field(s): {', '.join(unknown)} "
                            f"(expected {', '.join(GROW_KEYS)})")
    if "image" not in body:
        raise ApiError(400, "'image' is missing: draw a shape or upload a picture")
    gid = body.get("grammar", config.grammars[0].id)
    grammar = config.grammar(gid) if isinstance(gid, str) else None
    if grammar is None:
        raise ApiError(400, f"unknown grammar {gid!r}; choose from "
                            f"{', '.join(g.id for g in config.grammars)}")
    guide = None
    if "guide" not in body:
        guide = grammar.guides[0] if grammar.guides else None
    elif body["guide"] not in (None, "none"):
        guide = next((c for c in grammar.guides if c.id == body["guide"]), None)
        if guide is None:
            offer = ", ".join([c.id for c in grammar.guides] + ["null (unguided)"])
            raise ApiError(400, f"unknown guide {body['guide']!r} for grammar {grammar.id}; "
                                f"choose from {offer}")
    lim = config.limits
    particles = _int(body, "particles", lim.default_particles, 1, lim.max_particles)
    seed = _int(body, "seed", 0, 0, 2**32 - 1)
    start = parse_start(body.get("start"))
    polarity = _polarity(body)
    img = decode_image(body["image"], lim)
    try:
        mask, start = mask_from_image(img, lim.target_size, polarity, "picture", start)
        target = Target(mask, start if start is not None else auto_start(mask), "picture")
    except TargetError as err:
        raise ApiError(422, _target_message(err)) from None
    return Job(grammar, guide, target, particles, seed)


def _target_message(err: TargetError) -> str:
    text = str(err)
    if "flat" in text or "no shape" in text:
        return "the picture holds no shape: draw one (or upload a picture) first"
    return "the " + text if text.startswith("picture: ") else text


# --------------------------------------------------------------------------- runs


class RunStopped(Exception):
    """Raised inside SMC (by the RunCheck observer) to end a run early."""


@dataclass
class Run:
    client: str
    timeout_s: float
    cancel: threading.Event = field(default_factory=threading.Event)
    started: float = field(default_factory=time.monotonic)

    def check(self) -> None:
        if self.cancel.is_set():
            raise RunStopped("the run was stopped")
        if time.monotonic() - self.started > self.timeout_s:
            raise RunStopped(f"the run took longer than the {self.timeout_s:g} s time limit and "
                             "was stopped; try fewer particles")


class RunSlots:
    """One run per client address, at most `max_runs` runs at once."""

    def __init__(self, max_runs: int, timeout_s: float) -> None:
        self.max_runs = max_runs
        self.timeout_s = timeout_s
        self._lock = threading.Lock()
        self._active: dict[str, Run] = {}

    def acquire(self, client: str) -> Run:
        with self._lock:
            if client in self._active:
                raise ApiError(409, f"a run from your address ({client}) is still going: wait "
                                    "for it to finish or stop it first")
            if len(self._active) >= self.max_runs:
                raise ApiError(503, f"the server is busy with {len(self._active)} runs; try "
                                    "again in a moment", {"Retry-After": "2"})
            run = Run(client, self.timeout_s)
            self._active[client] = run
            return run

    def release(self, run: Run) -> None:
        with self._lock:
            if self._active.get(run.client) is run:
                del self._active[run.client]

    def active(self) -> int:
        with self._lock:
            return len(self._active)


def client_id(request: Request) -> str:
    """Whose run it is: the peer's address. Not a cookie or a header: those are the
    client's own word, and a client that changed them at will could take every slot."""
    return request.client.host if request.client else "unknown"


async def in_decode_slot(request: Request, work: Callable[..., Any], *args: Any) -> Any:
    """`work(*args)` (which decodes a picture) in a worker thread, holding one of the
    `max_runs` decode slots, so that many uploads at once cannot take the memory; 503 when
    every slot is taken. The thread itself gives the slot back, even if the request is
    abandoned meanwhile."""
    slots: threading.BoundedSemaphore = request.app.state.decode_slots
    if not slots.acquire(blocking=False):
        raise ApiError(503, "the server is busy reading other pictures; try again in a "
                            "moment", {"Retry-After": "2"})

    def held() -> Any:
        try:
            return work(*args)
        finally:
            slots.release()

    return await asyncio.to_thread(held)


def prim_json(p: tuple) -> list[Any]:
    """A primitive as JSON: [kind, numbers...] (poly: ["poly", [[x, y], ...]])."""
    if p[0] == "poly":
        return ["poly", [[round(float(x), 4), round(float(y), 4)] for x, y in p[1]]]
    return [p[0], *(round(float(v), 4) for v in p[1:])]


class RunCheck(SMCObserver):
    """Stops the run (RunStopped) after a step once it is cancelled or out of time."""

    def __init__(self, run: Run) -> None:
        self.run = run

    def step_done(self, state: SMCState) -> None:
        if state.drawn:
            self.run.check()


class FrameStream(SMCObserver):
    """After every SMC step that drew, the primitives of the best partial vine (highest
    log-likelihood so far) as a `frame` event, only what is new since the last one.

    Each particle's primitives are kept as a cons list in an object array registered in the
    run's per-particle state, so SMC's resampling carries them along."""

    KEY = "web_prims"

    def __init__(self, emit: Callable[[str, dict[str, Any]], None]) -> None:
        self.emit = emit
        self.sent: tuple | None = None  # the cons cell of the last frame
        self.steps = 0
        self.t0 = time.perf_counter()

    def step_done(self, state: SMCState) -> None:
        if not state.drawn:
            return
        self.steps += 1
        cells = state.arrays.get(self.KEY)
        if cells is None:
            cells = state.register(self.KEY, np.empty(state.n, dtype=object))
        for i, p in zip(state.drawn, state.prims, strict=True):
            cells[i] = (p, cells[i])
        best = int(np.argmax(np.nan_to_num(state.log_likelihood, nan=-np.inf)))
        node = cells[best]
        new: list[tuple] = []
        cur = node
        while cur is not None and cur is not self.sent:
            new.append(cur[0])
            cur = cur[1]
        if not new:
            return
        mode = "append" if cur is self.sent else "reset"
        self.sent = node
        self.emit("frame", {"step": self.steps, "mode": mode,
                            "seconds": round(time.perf_counter() - self.t0, 3),
                            "prims": [prim_json(p) for p in reversed(new)]})


def _grow(job: Job, observers: Sequence[SMCObserver] = ()) -> Any:
    """The one call of grow() (it moves to the runtime as ngpm_runtime.grow)."""
    from ngpm_runtime import grow

    return grow(job.grammar.program, job.target, job.guide.guide if job.guide else None,
                job.particles, job.seed, "shape", observers=observers)


def png_data_url(rgb: np.ndarray) -> str:
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format="PNG", optimize=True)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def mask_data_url(mask: np.ndarray, rgba: tuple[int, int, int, int]) -> str:
    """A mask as a PNG: `rgba` where it is set, transparent elsewhere."""
    out = np.zeros(mask.shape + (4,), dtype=np.uint8)
    out[np.asarray(mask, dtype=bool)] = rgba
    return png_data_url(out)


def target_event(job: Job) -> dict[str, Any]:
    program = job.grammar.program
    return {"viewport": [float(v) for v in program.viewport],
            "start": [round(v, 5) for v in job.target.start],
            "mask": mask_data_url(job.target.mask, MASK_RGBA),
            "size": list(job.target.size), "grammar": job.grammar.name,
            "guide": job.guide.name if job.guide else None,
            "particles": job.particles, "seed": job.seed}


def done_event(job: Job, res: Any, steps: int) -> dict[str, Any]:
    from ngpm_runtime.image.render import render_array, save_render

    vp = job.grammar.program.viewport
    mask = job.target.mask
    png = png_data_url(render_array(res.primitives, vp, RENDER_SIZE, mask))
    with tempfile.TemporaryDirectory(prefix="ngpm-serve-") as tmp:
        path = save_render(res.primitives, Path(tmp) / "vine.svg", vp, RENDER_SIZE, mask)
        svg = path.read_bytes()
    return {"similarity": round(float(res.similarity), 4), "seconds": round(res.seconds, 3),
            "particles": res.particles, "guided": job.guide is not None,
            "steps": int(getattr(res.smc, "steps", steps)),
            "primitives": [prim_json(p) for p in res.primitives],
            "png": png,
            "svg": "data:image/svg+xml;base64," + base64.b64encode(svg).decode("ascii")}


def run_job(job: Job, run: Run, slots: RunSlots,
            emit: Callable[[str, dict[str, Any]], None]) -> None:
    """The worker thread: target, frames, then done or error (after the slot is free)."""
    final: tuple[str, dict[str, Any]]
    try:
        emit("target", target_event(job))
        frames = FrameStream(emit)
        res = _grow(job, (RunCheck(run), frames))
        final = ("done", done_event(job, res, frames.steps))
    except RunStopped as err:
        final = ("error", {"error": str(err)})
    except NgpmError as err:
        final = ("error", {"error": str(err)})
    except Exception as err:  # never kill the server; the log has the traceback
        log.exception("run failed")
        final = ("error", {"error": f"internal error ({type(err).__name__}); the server log "
                                    "has details"})
    finally:
        slots.release(run)
    emit(*final)


def sse(event: str, data: dict[str, Any]) -> bytes:
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'))}\n\n".encode()


class RunStream(StreamingResponse):
    """A streaming response that calls `on_close` however it ends (done, error, client
    gone), so the worker stops at its next SMC step."""

    def __init__(self, content: Any, on_close: Callable[[], None]) -> None:
        super().__init__(content, media_type="text/event-stream",
                         headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})
        self.on_close = on_close

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        try:
            await super().__call__(scope, receive, send)
        finally:
            self.on_close()


# --------------------------------------------------------------------------- the app


async def index(request: Request) -> Response:
    return FileResponse(STATIC_DIR / "index.html", headers={"Cache-Control": "no-cache"})

async def options(request: Request) -> Response:
    config: WebConfig = request.app.state.config
    limits = config.limits
    from ngpm_runtime import bundled

    return JSONResponse({
        "grammars": [{"id": g.id, "name": g.name, "source": g.source,
                      "guides": [{"id": c.id, "name": c.name} for c in g.guides]}
                     for g in config.grammars],
        "examples": list(bundled.DEMO_TARGETS),
        "limits": {"max_particles": limits.max_particles,
                   "default_particles": limits.default_particles,
                   "max_image_bytes": limits.max_image_bytes,
                   "max_side": limits.max_side, "timeout_s": limits.timeout_s,
                   "target_size": limits.target_size},
    })

async def grow_route(request: Request) -> Response:
    config: WebConfig = request.app.state.config
    limits = config.limits
    slots: RunSlots = request.app.state.slots
    body = await read_json(request, limits.max_body_bytes)
    job = await in_decode_slot(request, parse_grow, body, config)
    run = slots.acquire(client_id(request))
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue[tuple[str, dict[str, Any]]] = asyncio.Queue()

    def emit(event: str, data: dict[str, Any]) -> None:
        try:
            loop.call_soon_threadsafe(queue.put_nowait, (event, data))
        except RuntimeError:  # the loop is gone (server shutting down)
            run.cancel.set()

    async def events() -> Any:
        while True:
            event, data = await queue.get()
            yield sse(event, data)
            if event in ("done", "error"):
                return

    worker = threading.Thread(target=run_job, args=(job, run, slots, emit),
                              name=f"ngpm-run-{run.client[:12]}", daemon=True)
    try:
        worker.start()
    except RuntimeError:
        slots.release(run)
        raise
    return RunStream(events(), run.cancel.set)

async def shape_route(request: Request) -> Response:
    limits = request.app.state.config.limits
    body = await read_json(request, limits.max_body_bytes)
    unknown = sorted(set(body) - {"image", "polarity"})
    if unknown:
        raise ApiError(400, f"unknown field(s): {', '.join(unknown)} (expected image, "
                            "polarity)")
    polarity = _polarity(body)
    return JSONResponse(await in_decode_slot(request, _shape, body.get("image"), polarity,
                                             limits))

async def examples(request: Request) -> Response:
    from ngpm_runtime import bundled

    return JSONResponse({"examples": list(bundled.DEMO_TARGETS)})

async def example(request: Request) -> Response:
    from ngpm_runtime import bundled
    from ngpm_runtime.image.targets import load_target

    name = request.path_params["name"]
    if name not in bundled.DEMO_TARGETS:
        raise ApiError(404, f"no example {name!r}; choose from "
                            f"{', '.join(bundled.DEMO_TARGETS)}")
    try:
        t = await asyncio.to_thread(load_target, bundled.demo_target_path(name), None)
    except TargetError as err:
        raise ApiError(500, str(err)) from None
    return JSONResponse({"name": name,
                         "mask": mask_data_url(shape_mask(t.mask), (0, 0, 0, 255)),
                         "start": [round(v, 5) for v in t.start]})


def create_app(config: WebConfig, hosts: tuple[str, ...] = HOSTS) -> Starlette:
    """The Starlette application serving the page and the API for `config`."""
    limits = config.limits
    slots = RunSlots(limits.max_runs, limits.timeout_s)
    routes = [
        Route("/", index),
        Route("/api/options", options),
        Route("/api/grow", grow_route, methods=["POST"]),
        Route("/api/shape", shape_route, methods=["POST"]),
        Route("/api/examples", examples),
        Route("/api/examples/{name}", example),
        Mount("/static", StaticFiles(directory=STATIC_DIR), name="static"),
    ]
    app = Starlette(
        routes=routes,
        middleware=[Middleware(TrustedHostMiddleware, allowed_hosts=list(hosts))],
        exception_handlers={ApiError: _api_error, HTTPException: _http_error,
                            Exception: _server_error},
    )
    app.state.config = config
    app.state.slots = slots
    app.state.decode_slots = threading.BoundedSemaphore(limits.max_runs)
    return app


def shape_mask(mask: np.ndarray, size: int = SHAPE_SIZE) -> np.ndarray:
    """A square mask at size x size: area-averaged down, or smoothly (bicubic) up, so that a
    small picture does not land on the canvas as big square pixels."""
    from ngpm_runtime.image.targets import resize_mask

    if mask.shape[0] >= size:
        return resize_mask(mask, size)
    from PIL import ImageFilter

    img = Image.fromarray(np.asarray(mask, dtype=np.uint8) * 255)
    big = img.resize((size, size), Image.Resampling.BICUBIC)
    big = big.filter(ImageFilter.GaussianBlur(0.6 * size / mask.shape[0]))
    return np.asarray(big) >= 128


def _shape(value: Any, polarity: str, limits: Limits) -> dict[str, Any]:
    from ngpm_runtime.image.targets import check_mask, mask_from_image

    img = decode_image(value, limits)
    try:
        mask, _ = mask_from_image(img, None, polarity, "picture")
        mask = shape_mask(mask)
        check_mask(mask, "picture")
    except TargetError as err:
        raise ApiError(422, _target_message(err)) from None
    return {"mask": mask_data_url(mask, (0, 0, 0, 255)), "size": list(mask.shape)}


# --------------------------------------------------------------------------- serving


def bind(port: int, host: str = "127.0.0.1") -> socket.socket:
    """A listening socket on host:port (port 0: any free port)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError:
        sock.close()
        raise
    sock.listen(64)
    sock.set_inheritable(True)
    return sock


def warm_up(config: WebConfig) -> None:
    """A tiny run on a demo picture with each grammar's first guide, so that the first
    visitor does not wait for imports and onnxruntime's first calls."""
    from ngpm_runtime import bundled
    from ngpm_runtime.image.targets import load_target

    try:
        target = load_target(bundled.demo_target_path("heart"), config.limits.target_size)
        for g in config.grammars:
            job = Job(g, g.guides[0] if g.guides else None, target, 2, 0)
            done_event(job, _grow(job), 0)
    except Exception as err:  # a warm-up problem is not worth refusing to start over
        log.warning("warm-up run failed: %s", err)


def make_server(config: WebConfig, sock: socket.socket, log_level: str = "warning") -> Any:
    """A uvicorn Server for the app (after a warm-up run); run it with
    `server.run(sockets=[sock])`. Requests must arrive within `request_timeout_s`, and at
    most `max_connections` connections are served at once (uvicorn answers 503 beyond)."""
    import uvicorn

    warm_up(config)

    host, port = sock.getsockname()[:2]
    hosts = tuple(sorted(set(HOSTS) | {host}))
    limits = config.limits
    uconfig = uvicorn.Config(create_app(config, hosts), log_level=log_level,
                             access_log=False, timeout_graceful_shutdown=2,
                             http=deadline_protocol(limits.request_timeout_s),
                             limit_concurrency=limits.max_connections)
    return uvicorn.Server(uconfig)


def deadline_protocol(timeout_s: float) -> type[asyncio.Protocol]:
    """uvicorn's HTTP/1.1 protocol (h11) with a deadline: a request's line, headers and body
    must arrive within `timeout_s` of the connection opening (or of the previous response),
    else the connection is closed. uvicorn has no such timeout: its keep-alive timeout
    starts only after a response and any byte resets it, so a client sending a byte now
    and then would hold its connection forever."""
    import h11
    from uvicorn.protocols.http.h11_impl import H11Protocol

    arriving = (h11.IDLE, h11.SEND_BODY)  # the client's states while a request comes in

    class DeadlineProtocol(H11Protocol):
        deadline: asyncio.TimerHandle | None = None

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            self._arm()

        def data_received(self, data: bytes) -> None:
            super().data_received(data)
            if self.conn.their_state not in arriving:  # the request is in (or it failed)
                self._disarm()

        def on_response_complete(self) -> None:
            super().on_response_complete()
            self._disarm()
            if not self.transport.is_closing() and self.conn.their_state in arriving:
                self._arm()  # the next request (or the rest of this one's body)

        def connection_lost(self, exc: Exception | None) -> None:
            self._disarm()
            super().connection_lost(exc)

        def _arm(self) -> None:
            self._disarm()
            self.deadline = self.loop.call_later(timeout_s, self._expire)

        def _disarm(self) -> None:
            if self.deadline is not None:
                self.deadline.cancel()
                self.deadline = None

        def _expire(self) -> None:
            self.deadline = None
            if not self.transport.is_closing():
                self.transport.close()

    return DeadlineProtocol
