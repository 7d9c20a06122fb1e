"""The ledger of model revisions: each revision's held-out error on the same measurements, kept
across runs (results/<experiment>/diagnosis/ledger.json, not a rule output), so the diagnosis can
show the error falling as effects are added."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from helioflow.errors import DataError
from helioflow.io import write_text_atomic


def model_hash(effects: dict) -> str:
    """Short hash of a model effect list's content: the ledger's key for a model revision."""
    return hashlib.sha256(json.dumps(effects, sort_keys=True).encode()).hexdigest()[:10]


def read_ledger(path: str | os.PathLike) -> list[dict]:
    """The revisions in the ledger at `path` (none when it does not exist yet); DataError names the
    file when it is not a ledger. Read before the fits, so that a broken ledger costs no run."""
    path = Path(path)
    if not path.exists():
        return []
    try:
        entries = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataError(f"{path}: not a readable ledger (JSON list of model revisions): {exc}; "
                        "repair it or delete it to start a new ledger") from None
    keys = ("revision", "model_hash", "dataset_hash", "model_effects", "heldout_error")
    if not isinstance(entries, list) or not all(isinstance(e, dict) and all(k in e for k in keys) for e in entries):
        raise DataError(f"{path}: expected a JSON list of model revisions, each with {', '.join(keys)}; "
                        "repair it or delete it to start a new ledger")
    return entries


def revised(entries: list[dict], dataset_hash: str, effects: dict, error: float) -> tuple[list[dict], list[dict]]:
    """(every entry of the ledger `entries` with this model revision's held-out error recorded, the
    revisions on the same measurements, oldest first, the newest marked `current`). A rerun of the
    newest revision (same model effect list) replaces it; any other model, one tried before included
    (going back), is a new revision. `entries` is changed in place."""
    key = model_hash(effects)
    same = [e for e in entries if e["dataset_hash"] == dataset_hash]
    if same and same[-1]["model_hash"] == key:
        entry = same[-1]
    else:
        entry = {"revision": len(same) + 1, "model_hash": key, "dataset_hash": dataset_hash, "model_effects": effects}
        entries.append(entry)
        same.append(entry)
    entry["heldout_error"] = error
    for e in same:
        e["current"] = e is entry
    return entries, same


def write_ledger(path: str | os.PathLike, entries: list[dict]) -> None:
    """Write the ledger `entries` (`revised`) to `path`."""
    write_text_atomic(path, json.dumps(entries, indent=1))


def update_ledger(path: str | os.PathLike, dataset_hash: str, effects: dict, error: float) -> list[dict]:
    """Record the held-out error of this model revision in the ledger at `path` (`revised`) and
    return the revisions on the same measurements."""
    entries, same = revised(read_ledger(path), dataset_hash, effects, error)
    write_ledger(path, entries)
    return same
