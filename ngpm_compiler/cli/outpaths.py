"""Output paths checked before a command does any work, so a long job never fails at the end
for a path it could have refused at the start."""

from __future__ import annotations

import os
from pathlib import Path

from ngpm_runtime.errors import NgpmError


def check_output_file(path: str | os.PathLike[str], what: str = "file") -> Path:
    """NgpmError unless `path` can be written as a file: not a folder, in a writable folder."""
    path = Path(path)
    folder = path.parent
    if path.is_dir():
        raise NgpmError(f"{path}: is a folder; -o wants the {what} to write")
    if not folder.is_dir():
        raise NgpmError(f"{path}: cannot write there (no folder {folder})")
    if not os.access(folder, os.W_OK):
        raise NgpmError(f"{path}: cannot write there (permission denied)")
    return path


def check_output_folder(path: str | os.PathLike[str]) -> Path:
    """NgpmError unless `path` is a folder or can be made one."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise NgpmError(
            f"{path}: is a file; -o wants a folder (the outputs are named after the grammar)"
        )
    return path
