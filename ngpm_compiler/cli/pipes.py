"""Standard output that may be a pipe closed early (`ngpmc grow ... | head -1`).

The Unix way: once the reader is gone, what the command would print is dropped silently,
and the command goes on to finish its real work (files are still written)."""

from __future__ import annotations

import os
import sys
from typing import Any, TextIO


class PipeSafeStdout:
    """A text stream that forwards to `inner` until the reader closes the pipe, then
    discards (and points the file descriptor at /dev/null, so interpreter shutdown's
    flush does not complain either)."""

    def __init__(self, inner: TextIO) -> None:
        self.inner = inner
        self.broken = False

    def _close_pipe(self) -> None:
        self.broken = True
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, self.inner.fileno())
            os.close(devnull)
        except (OSError, ValueError, AttributeError):
            pass

    def write(self, text: str) -> int:
        if not self.broken:
            try:
                return self.inner.write(text)
            except BrokenPipeError:
                self._close_pipe()
        return len(text)

    def flush(self) -> None:
        if not self.broken:
            try:
                self.inner.flush()
            except BrokenPipeError:
                self._close_pipe()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


def install() -> TextIO:
    """Wrap sys.stdout; returns the stream it wrapped (to put back with `restore`)."""
    old = sys.stdout
    if not isinstance(old, PipeSafeStdout):
        sys.stdout = PipeSafeStdout(old)
    return old


def restore(old: TextIO) -> None:
    wrapped = sys.stdout
    if isinstance(wrapped, PipeSafeStdout):
        wrapped.flush()
    sys.stdout = old
