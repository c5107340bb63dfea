"""The routes of `ngpmc serve` (every error is JSON `{"error": "..."}` with a fitting status
code):

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
"""

from __future__ import annotations

import asyncio
import logging
import threading
from pathlib import Path
from typing import Any

import numpy as np
from ngpm_runtime.errors import TargetError
from PIL import Image
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response

from ngpm_compiler.web.config import Limits, WebConfig
from ngpm_compiler.web.runs import RunSlots, client_id, in_decode_slot, run_job
from ngpm_compiler.web.sse import RunStream, mask_data_url, sse
from ngpm_compiler.web.validate import (
    ApiError,
    decode_image,
    parse_grow,
    parse_polarity,
    read_json,
    target_message,
)

log = logging.getLogger("ngpmc.serve")

STATIC_DIR = Path(__file__).resolve().parent / "static"
SHAPE_SIZE = 256  # side of the masks /api/shape and /api/examples return


def error_json(status: int, message: str, headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status, headers=headers)


async def api_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, ApiError)
    return error_json(exc.status, exc.message, exc.headers)


async def http_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, HTTPException)
    messages = {
        404: f"no such page: {request.url.path}",
        405: f"{request.method} is not allowed on {request.url.path}",
    }
    return error_json(
        exc.status_code,
        messages.get(exc.status_code, str(exc.detail)),
        dict(exc.headers) if exc.headers else None,
    )


async def server_error(request: Request, exc: Exception) -> Response:
    log.error("internal error on %s %s", request.method, request.url.path, exc_info=exc)
    return error_json(500, f"internal error ({type(exc).__name__}); the server log has details")


async def index(request: Request) -> Response:
    return FileResponse(STATIC_DIR / "index.html", headers={"Cache-Control": "no-cache"})


async def options(request: Request) -> Response:
    config: WebConfig = request.app.state.config
    limits = config.limits
    from ngpm_runtime import bundled

    return JSONResponse(
        {
            "grammars": [
                {
                    "id": g.id,
                    "name": g.name,
                    "source": g.source,
                    "guides": [{"id": c.id, "name": c.name} for c in g.guides],
                }
                for g in config.grammars
            ],
            "examples": list(bundled.DEMO_TARGETS),
            "limits": {
                "max_particles": limits.max_particles,
                "default_particles": limits.default_particles,
                "max_image_bytes": limits.max_image_bytes,
                "max_side": limits.max_side,
                "timeout_s": limits.timeout_s,
                "target_size": limits.target_size,
            },
        }
    )


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

    worker = threading.Thread(
        target=run_job,
        args=(job, run, slots, emit),
        name=f"ngpm-run-{run.client[:12]}",
        daemon=True,
    )
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
        raise ApiError(400, f"unknown field(s): {', '.join(unknown)} (expected image, polarity)")
    polarity = parse_polarity(body)
    return JSONResponse(await in_decode_slot(request, _shape, body.get("image"), polarity, limits))


async def examples(request: Request) -> Response:
    from ngpm_runtime import bundled

    return JSONResponse({"examples": list(bundled.DEMO_TARGETS)})


async def example(request: Request) -> Response:
    from ngpm_runtime import bundled
    from ngpm_runtime.image.targets import load_target

    name = request.path_params["name"]
    if name not in bundled.DEMO_TARGETS:
        raise ApiError(404, f"no example {name!r}; choose from {', '.join(bundled.DEMO_TARGETS)}")
    try:
        t = await asyncio.to_thread(load_target, bundled.demo_target_path(name), None)
    except TargetError as err:
        raise ApiError(500, str(err)) from None
    return JSONResponse(
        {
            "name": name,
            "mask": mask_data_url(shape_mask(t.mask), (0, 0, 0, 255)),
            "start": [round(v, 5) for v in t.start],
        }
    )


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
        raise ApiError(422, target_message(err)) from None
    return {"mask": mask_data_url(mask, (0, 0, 0, 255)), "size": list(mask.shape)}
