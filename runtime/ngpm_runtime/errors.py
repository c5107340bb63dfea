"""Errors the runtime raises. Each prints as one line that names the cause."""


def printable(text: str) -> str:
    """`text` for a one-line message: characters that are not printable (a newline in a
    file name, say) are shown as escapes such as `\\n`."""
    return (
        text
        if text.isprintable()
        else "".join(c if c.isprintable() else ascii(c)[1:-1] for c in text)
    )


class NgpmError(Exception):
    """Base of every error ngpm reports to a user (one line, no traceback)."""

    exit_code = 1


class SMCFailed(NgpmError):
    """Every particle's weight became zero (or not finite)."""


class TargetError(NgpmError):
    """A target image or its sidecar cannot be used."""


class GuideError(NgpmError):
    """A guide file is corrupt or belongs to another grammar."""


class ProgramError(NgpmError):
    """A generated program is missing, corrupt or misbehaves at run time."""
