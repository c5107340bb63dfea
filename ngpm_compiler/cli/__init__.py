"""The `ngpmc` command line. Each command family lives in its own module of this package
that defines `register(subparsers)`; handlers parse arguments, call library functions and
return an exit code."""

from __future__ import annotations

import argparse
import importlib
import sys

from ngpm_runtime.errors import NgpmError

from ngpm_compiler.cli import pipes
from ngpm_compiler.cli.extras import missing_extra

# Command-family modules, in the order `ngpmc --help` lists them.
COMMAND_MODULES = [
    "ngpm_compiler.cli.grammar",  # compile, check, sample
    "ngpm_compiler.cli.guide",  # traces, train, iterate, export, tune
    "ngpm_compiler.cli.learn",  # learn
    "ngpm_compiler.cli.grow",  # grow
    "ngpm_compiler.cli.targets",  # targets build, list, show
    "ngpm_compiler.cli.evaluate",  # eval
    "ngpm_compiler.cli.demo",  # demo
    "ngpm_compiler.cli.serve",  # serve (needs the [web] extra)
]
# commands that run SMC: the first on a machine compiles the kernels (a note says so)
KERNEL_COMMANDS = {"grow", "traces", "iterate", "tune", "eval", "demo", "serve", "learn"}


class _Version(argparse.Action):
    """--version, looked up only when asked (start-up stays free of importlib.metadata)."""

    def __call__(self, parser: argparse.ArgumentParser, *_: object) -> None:
        from importlib.metadata import PackageNotFoundError, version

        try:
            text = version("ngpm")
        except PackageNotFoundError:  # a checkout that is not installed
            text = "(not installed)"
        print(f"ngpmc {text}")
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ngpmc", description="Compile, train and grow neurally-guided procedural models."
    )
    parser.add_argument(
        "--version", action=_Version, nargs=0, help="show the version of ngpm and exit"
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(subparsers)
    return parser


def _note_cold_kernels(command: str) -> None:
    """One line on stderr when a command is about to compile the SMC kernels."""
    if command in KERNEL_COMMANDS:
        from ngpm_runtime.warmup import COLD_NOTE, cache_is_cold

        if cache_is_cold():
            print(f"ngpmc: {COLD_NOTE}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "handler", None):
        parser.print_help()
        return 2
    stdout = pipes.install()
    try:
        _note_cold_kernels(args.command)
        return int(args.handler(args) or 0)
    except NgpmError as err:
        print(f"ngpmc: error: {err}", file=sys.stderr)
        return err.exit_code
    except ImportError as err:
        hint = missing_extra(args.command, err)
        if hint is None:
            raise
        print(f"ngpmc: error: {hint}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("ngpmc: interrupted", file=sys.stderr)
        return 130
    except OSError as err:
        print(
            f"ngpmc: error: {err.strerror or err}: {err.filename or ''}".rstrip(": "),
            file=sys.stderr,
        )
        return 1
    finally:
        pipes.restore(stdout)
