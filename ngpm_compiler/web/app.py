"""The `ngpmc serve` application: sketch a shape in the browser, watch SMC grow a vine into it.

The parts: `config.py` (what is on offer, `Limits`), `validate.py` (checks of what a client
sends), `runs.py` (run slots, the worker thread), `sse.py` (the event stream of a run),
`routes.py` (the API; its docstring lists the routes); here the application and its server.

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
import logging
import socket
import threading
from typing import Any

from starlette.applications import Starlette
from starlette.exceptions import HTTPException
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from ngpm_compiler.web.config import WebConfig
from ngpm_compiler.web.routes import (
    STATIC_DIR,
    api_error,
    example,
    examples,
    grow_route,
    http_error,
    index,
    options,
    server_error,
    shape_route,
)
from ngpm_compiler.web.runs import RunSlots, grow_job
from ngpm_compiler.web.sse import done_event
from ngpm_compiler.web.validate import ApiError, Job

log = logging.getLogger("ngpmc.serve")

HOSTS = ("127.0.0.1", "localhost", "[::1]")


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
        exception_handlers={
            ApiError: api_error,
            HTTPException: http_error,
            Exception: server_error,
        },
    )
    app.state.config = config
    app.state.slots = slots
    app.state.decode_slots = threading.BoundedSemaphore(limits.max_runs)
    return app


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
            done_event(job, grow_job(job), 0)
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
    uconfig = uvicorn.Config(
        create_app(config, hosts),
        log_level=log_level,
        access_log=False,
        timeout_graceful_shutdown=2,
        http=deadline_protocol(limits.request_timeout_s),
        limit_concurrency=limits.max_connections,
    )
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
