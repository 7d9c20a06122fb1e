"""Files written whole or not at all, torch files read with a clear error, and fingerprints.

The one place for them: every output of the pipeline goes through `write_atomic`, so a killed or
failed job (a full disk included) leaves neither a half-written file that looks complete nor a
temporary file holding the space.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from dataclasses import fields, is_dataclass
from pathlib import Path

import torch
from torch import Tensor

from helioflow.errors import DataError, OutputError


def write_atomic(path: str | os.PathLike, write: Callable[[Path], object]) -> None:
    """Write a file with `write(temporary path)` under a temporary name (`.<name>.tmp` beside it),
    then rename it into place; makes its folder. If writing fails, the temporary file is removed
    and OutputError names the file (an OSError such as a full disk, or torch's RuntimeError for
    the same); `path` is left as it was."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write(tmp)
        os.replace(tmp, path)
    except (OSError, RuntimeError) as exc:
        tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError) and exc.strerror:
            reason = exc.strerror
        else:  # torch.save reports a failed write (a full disk among others) as a RuntimeError
            reason = f"the write failed (is the disk full?): {(str(exc).splitlines() or [type(exc).__name__])[0]}"
        raise OutputError(f"cannot write {path}: {reason}") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """A text file (UTF-8), written whole (`write_atomic`)."""
    write_atomic(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def save_torch_atomic(path: str | os.PathLike, obj) -> None:
    """`torch.save(obj)` to a file written whole (`write_atomic`)."""
    write_atomic(path, lambda tmp: torch.save(obj, tmp))


def load_torch(path: str | os.PathLike, what: str) -> dict:
    """A dict saved by `save_torch_atomic`, on the CPU; DataError names the file and `what` it should
    be (e.g. "a helioflow model file") when it is missing, truncated, corrupt or holds no dict."""
    try:
        obj = torch.load(path, weights_only=False, map_location="cpu")
    except FileNotFoundError:
        raise DataError(f"{path} does not exist (expected {what})") from None
    except Exception as exc:  # torch.load raises pickle, zip, EOF and runtime errors on a corrupt file
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DataError(f"{path} is not {what} (truncated or corrupt?): {reason}") from None
    if not isinstance(obj, dict):
        raise DataError(f"{path} is not {what}: it holds a {type(obj).__name__}")
    return obj


def fingerprint(*parts) -> str:
    """SHA-256 (hex) of `parts`: tensors by their dtype, shape and bytes, dataclasses by
    their fields, dicts, lists and tuples by their items, anything else by its repr. What a
    resumable state (a fit's or a training's checkpoint) holds, so that only the computation that
    wrote it resumes it."""
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
