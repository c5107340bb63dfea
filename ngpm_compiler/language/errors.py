"""Errors the compiler reports for a malformed grammar."""

from __future__ import annotations

from ngpm_runtime.errors import NgpmError, printable


class GrammarError(NgpmError):
    """A grammar cannot be compiled: `file:line:col: message`, the line, and a caret."""

    exit_code = 2

    def __init__(
        self,
        message: str,
        filename: str = "<grammar>",
        line: int = 1,
        col: int = 1,
        source: str = "",
    ) -> None:
        self.message = message
        self.filename = filename
        self.line = max(1, line)
        self.col = max(1, col)
        self.source = source
        super().__init__(self.format())

    def format(self) -> str:
        head = f"{printable(self.filename)}:{self.line}:{self.col}: {self.message}"
        lines = self.source.splitlines()
        if not 1 <= self.line <= len(lines):
            return head
        text = lines[self.line - 1]
        # keep tabs in the caret line so the caret sits under the column
        pad = "".join(c if c == "\t" else " " for c in text[: self.col - 1])
        return f"{head}\n{text}\n{pad}^"


class ErrorSink:
    """Builds GrammarErrors for one source file."""

    def __init__(self, filename: str, source: str) -> None:
        self.filename = filename
        self.source = source

    def error(self, message: str, line: int, col: int) -> GrammarError:
        return GrammarError(message, self.filename, line, col, self.source)
