"""Which extra a command needs when an optional package is missing."""

from __future__ import annotations

# Optional packages -> the extra that installs them (pyproject.toml).
EXTRAS = {
    "torch": "train",
    "starlette": "web",
    "uvicorn": "web",
    "ray": "cluster",
    "skimage": "eval",
    "matplotlib": "eval",
}
# Where a command needs a package for another extra's reason: `targets build glyphs` takes
# its default font from matplotlib, which [train] installs for the validation glyphs.
COMMAND_EXTRAS = {("targets", "matplotlib"): "train"}


def missing_extra(command: str, err: ImportError) -> str | None:
    """The one-line hint for a command whose extra is not installed, or None."""
    top = (err.name or "").split(".")[0]
    extra = COMMAND_EXTRAS.get((command, top), EXTRAS.get(top))
    if extra is None:
        return None
    hint = " (README: PyTorch's CPU-only wheels)" if extra == "train" else ""
    return (
        f"ngpmc {command} needs the {extra} extra ({top} is missing): "
        f'pip install -e ".[{extra}]"{hint}'
    )
