"""The event stream of a run (`text/event-stream`): the `target` event, the `frame` events
while SMC runs (`FrameStream`), the `done` event with the downloads, and the response that
carries them (`RunStream`)."""

from __future__ import annotations

import base64
import io
import json
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from ngpm_runtime.geometry.turtle import Prim
from ngpm_runtime.grow import GrowResult
from ngpm_runtime.inference.smc import SMCObserver, SMCState
from PIL import Image
from starlette.responses import StreamingResponse
from starlette.types import Receive, Scope, Send

from ngpm_compiler.web.validate import Job

RENDER_SIZE = 512  # side of the PNG and SVG downloads
MASK_RGBA = (150, 168, 200, 255)  # the target as the page shows it (a light blue-gray)

Emit = Callable[[str, dict[str, Any]], None]  # sends one event: emit(name, data)


def prim_json(p: Prim) -> list[Any]:
    """A primitive as JSON: [kind, numbers...] (poly: ["poly", [[x, y], ...]])."""
    if p[0] == "poly":
        return ["poly", [[round(float(x), 4), round(float(y), 4)] for x, y in p[1]]]
    return [p[0], *(round(float(v), 4) for v in p[1:])]


class FrameStream(SMCObserver):
    """After every SMC step that drew, the primitives of the best partial vine (highest
    log-likelihood so far) as a `frame` event, only what is new since the last one.

    Each particle's primitives are kept as a cons list in an object array registered in the
    run's per-particle state, so SMC's resampling carries them along."""

    KEY = "web_prims"

    def __init__(self, emit: Emit) -> None:
        self.emit = emit
        self.sent: tuple[Prim, Any] | None = None  # the cons cell of the last frame
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
        new: list[Prim] = []
        cur = node
        while cur is not None and cur is not self.sent:
            new.append(cur[0])
            cur = cur[1]
        if not new:
            return
        mode = "append" if cur is self.sent else "reset"
        self.sent = node
        self.emit(
            "frame",
            {
                "step": self.steps,
                "mode": mode,
                "seconds": round(time.perf_counter() - self.t0, 3),
                "prims": [prim_json(p) for p in reversed(new)],
            },
        )


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
    viewport = job.grammar.program.viewport
    assert viewport is not None  # load_config refuses a grammar without one
    return {
        "viewport": [float(v) for v in viewport],
        "start": [round(v, 5) for v in job.target.start],
        "mask": mask_data_url(job.target.mask, MASK_RGBA),
        "size": list(job.target.size),
        "grammar": job.grammar.name,
        "guide": job.guide.name if job.guide else None,
        "particles": job.particles,
        "seed": job.seed,
    }


def done_event(job: Job, res: GrowResult, steps: int) -> dict[str, Any]:
    from ngpm_runtime.image.render import render_array, save_render

    vp = job.grammar.program.viewport
    mask = job.target.mask
    png = png_data_url(render_array(res.primitives, vp, RENDER_SIZE, mask))
    with tempfile.TemporaryDirectory(prefix="ngpm-serve-") as tmp:
        path = save_render(res.primitives, Path(tmp) / "vine.svg", vp, RENDER_SIZE, mask)
        svg = path.read_bytes()
    return {
        "similarity": round(float(res.similarity), 4),
        "seconds": round(res.seconds, 3),
        "particles": res.particles,
        "guided": job.guide is not None,
        "steps": int(getattr(res.smc, "steps", steps)),
        "primitives": [prim_json(p) for p in res.primitives],
        "png": png,
        "svg": "data:image/svg+xml;base64," + base64.b64encode(svg).decode("ascii"),
    }


def sse(event: str, data: dict[str, Any]) -> bytes:
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'))}\n\n".encode()


class RunStream(StreamingResponse):
    """A streaming response that calls `on_close` however it ends (done, error, client
    gone), so the worker stops at its next SMC step."""

    def __init__(self, content: Any, on_close: Callable[[], None]) -> None:
        super().__init__(
            content,
            media_type="text/event-stream",
            headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"},
        )
        self.on_close = on_close

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        try:
            await super().__call__(scope, receive, send)
        finally:
            self.on_close()
