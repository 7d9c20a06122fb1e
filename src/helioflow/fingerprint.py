"""One hash of what a computation depends on, so that a resumable state (a fit's or a training's
checkpoint) is only resumed by the computation that wrote it."""

from __future__ import annotations

import hashlib
from dataclasses import fields, is_dataclass

from torch import Tensor


def fingerprint(*parts) -> str:
    """SHA-256 (hex) of `parts`: tensors by their dtype, shape and bytes, dataclasses by
    their fields, dicts, lists and tuples by their items, anything else by its repr."""
    digest = hashlib.sha256()

    def feed(x) -> None:
        if isinstance(x, Tensor):
            digest.update(f"{x.dtype}{tuple(x.shape)}".encode())
            digest.update(x.detach().cpu().contiguous().numpy().tobytes())
        elif is_dataclass(x):
            digest.update(type(x).__name__.encode())
            for f in fields(x):
                feed(f.name)
                feed(getattr(x, f.name))
        elif isinstance(x, dict):
            for k, v in x.items():
                feed(k)
                feed(v)
        elif isinstance(x, (list, tuple)):
            digest.update(f"{type(x).__name__}{len(x)}".encode())
            for v in x:
                feed(v)
        else:
            digest.update(repr(x).encode())

    for part in parts:
        feed(part)
    return digest.hexdigest()
