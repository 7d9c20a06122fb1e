"""Output files written whole or not at all: a killed rule leaves no half-written file that looks complete."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import torch


def write_atomic(path: str | os.PathLike, write: Callable[[Path], None]) -> None:
    """Write a file with `write(temporary path)` under a temporary name, then rename it into place;
    makes its folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    write(tmp)
    os.replace(tmp, path)


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """A text file (UTF-8), written whole (`write_atomic`)."""
    write_atomic(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def save_torch_atomic(path: str | os.PathLike, obj) -> None:
    """`torch.save(obj)` to a file written whole (`write_atomic`)."""
    write_atomic(path, lambda tmp: torch.save(obj, tmp))
