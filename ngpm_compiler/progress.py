"""Progress of long commands: a tqdm bar on a terminal, a plain line every few seconds
otherwise, and a last one at the end if any was printed (log files get a handful of
readable lines, not thousands of bar updates)."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import Any, TextIO

PLAIN_INTERVAL = 10.0  # seconds between plain progress lines
Log = Callable[[str], None]  # where long jobs report a line: print, or a log file's writer


class Progress:
    """Counts `unit`s of `desc` up to `total`; `enabled=False` shows nothing."""

    def __init__(
        self,
        desc: str,
        total: int | None = None,
        unit: str = "it",
        initial: int = 0,
        enabled: bool = True,
        stream: TextIO | None = None,
        interval: float = PLAIN_INTERVAL,
        delay: float = 0.0,
        leave: bool = True,
    ) -> None:
        self.desc, self.total, self.unit, self.n = desc, total, unit, initial
        self.stream = stream or sys.stderr
        self.interval, self.enabled = interval, enabled
        self.postfix: dict[str, Any] = {}
        self.start = self.last = time.monotonic()
        self.bar: Any = None
        self.lines = 0  # plain lines printed
        if enabled and self.stream.isatty():
            from tqdm import tqdm

            self.bar = tqdm(
                total=total,
                initial=initial,
                desc=desc,
                unit=unit,
                file=self.stream,
                delay=delay,
                leave=leave,
            )

    def update(self, n: int = 1) -> None:
        self.n += n
        if self.bar is not None:
            self.bar.update(n)
        elif self.enabled and time.monotonic() - self.last >= self.interval:
            self._line()

    def set_postfix(self, **values: Any) -> None:
        self.postfix.update(values)
        if self.bar is not None:
            self.bar.set_postfix(**values)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        elif self.enabled and self.lines:  # a long job ends with its last count
            self._line()
        self.enabled = False

    def _line(self) -> None:
        self.last = time.monotonic()
        self.lines += 1
        done = f"{self.n}/{self.total}" if self.total else str(self.n)
        extra = "".join(f", {k} {v}" for k, v in self.postfix.items())
        print(
            f"{self.desc}: {done} {self.unit}s, {self.last - self.start:.0f} s{extra}",
            file=self.stream,
            flush=True,
        )

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
