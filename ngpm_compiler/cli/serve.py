"""`ngpmc serve`: a local web page where you sketch a shape and watch a guided vine grow."""

from __future__ import annotations

import argparse

from ngpm_runtime.errors import NgpmError

from ngpm_compiler.cli import argtypes
from ngpm_compiler.cli.extras import missing_extra
from ngpm_compiler.cli.grammar import GRAMMAR_HELP


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "serve",
        help="a local web page: draw a shape, watch a guided vine grow into it",
        description="Start a local web server (127.0.0.1 only) with a page where you draw a "
        "shape or upload a picture and watch guided SMC grow a vine into it. It "
        "offers the bundled vines model and guide, plus --grammar/--guide.",
    )
    p.add_argument(
        "--port",
        type=argtypes.integer(0, 65535),
        default=8000,
        help="port on 127.0.0.1 (default 8000; 0 picks a free one)",
    )
    p.add_argument(
        "--grammar",
        help=f"also offer this grammar (default: only the bundled vines): {GRAMMAR_HELP}",
    )
    p.add_argument(
        "--guide",
        help="guide .onnx for --grammar (alone: another guide for the "
        "bundled vines), or 'none' (default: the bundled guide "
        "where one fits)",
    )
    p.add_argument(
        "--max-particles",
        type=argtypes.particles,
        default=500,
        help="the most particles a run may ask for (default 500)",
    )
    p.add_argument(
        "--timeout",
        type=argtypes.positive_number(argtypes.MAX_TIMEOUT),
        default=60.0,
        help="seconds a run may take before it is stopped "
        f"(default 60, at most {argtypes.MAX_TIMEOUT:g})",
    )
    p.add_argument(
        "--max-runs",
        type=argtypes.workers,
        default=2,
        help="runs at once over all clients, and pictures read at once (default 2)",
    )
    p.add_argument("--open", action="store_true", help="open the page in a web browser")
    p.set_defaults(handler=cmd_serve)


def cmd_serve(args: argparse.Namespace) -> int:
    try:
        import starlette  # noqa: F401
        import uvicorn  # noqa: F401
    except ImportError as err:
        raise NgpmError(missing_extra("serve", err) or str(err)) from None
    from ngpm_compiler.web.app import bind, make_server
    from ngpm_compiler.web.config import Limits, load_config

    if not 0 <= args.port <= 65535:
        raise NgpmError(f"--port must be from 0 to 65535, got {args.port}")
    if args.max_particles < 1 or args.max_runs < 1 or not args.timeout > 0:
        raise NgpmError("--max-particles, --max-runs and --timeout must be positive")
    limits = Limits(
        max_particles=args.max_particles,
        timeout_s=args.timeout,
        max_runs=args.max_runs,
        default_particles=min(Limits.default_particles, args.max_particles),
    )
    config = load_config(args.grammar, args.guide, limits)
    try:
        sock = bind(args.port)
    except OSError as err:
        raise NgpmError(
            f"cannot listen on 127.0.0.1:{args.port}: {err.strerror or err} "
            "(try another --port, or --port 0)"
        ) from None
    url = f"http://127.0.0.1:{sock.getsockname()[1]}/"
    names = ", ".join(
        f"{g.name} ({len(g.guides)} guide{'s' * (len(g.guides) != 1)})" for g in config.grammars
    )
    print(f"ngpmc serve: {names}")
    print(f"ngpmc serve: open {url}  (Ctrl-C stops the server)", flush=True)
    if args.open:
        import webbrowser

        webbrowser.open(url)
    try:
        make_server(config, sock).run(sockets=[sock])
    except KeyboardInterrupt:  # uvicorn shut down cleanly, then passes Ctrl-C on
        pass
    finally:
        sock.close()
    print("ngpmc serve: stopped")
    return 0
