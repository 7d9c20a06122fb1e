"""Table 1: PSNR and SSIM of every network on every dataset, per split, from the metrics JSONs."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from helioflow.data.hdf5 import SPLITS
from helioflow.errors import DataError
from helioflow.io import write_text_atomic

NETWORK_ORDER = ("nearest", "gan", "cgan", "nerf")
DASH = "–"
SPLIT_LABELS = {"train": "train", "interpolation": "interp.", "extrapolation": "extrap."}
CSV_COLUMNS = ("network", "dataset", "controllable",
               *(f"{m}_{s}" for m in ("psnr", "ssim") for s in SPLITS), *(f"n_{s}" for s in SPLITS))


def _network_key(network: str) -> tuple[int, str]:
    """Fixed order nearest, gan, cgan, nerf, then any other network alphabetically."""
    return (NETWORK_ORDER.index(network), "") if network in NETWORK_ORDER else (len(NETWORK_ORDER), network)


def _load(path) -> dict:
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
        for key in ("network", "dataset", "controllable", "splits"):
            data[key]
        for split in SPLITS:
            for key in ("psnr", "ssim", "n"):
                data["splits"][split][key]
    except OSError as exc:
        raise DataError(f"{path}: cannot read metrics file: {exc}") from None
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise DataError(f"{path}: not a helioflow metrics JSON (written by `evaluate`): missing or bad {exc}") from None
    return data


def controllability(data: dict) -> str:
    """'yes', or 'no (best of N samples)' for an unconditioned network."""
    if data["controllable"]:
        return "yes"
    n = data.get("samples")
    return f"no (best of {n} samples)" if n else "no (best of N samples)"


def _fmt(value, digits: int) -> str:
    return DASH if value is None else f"{value:.{digits}f}"


def build_table(metrics_paths: list, out_csv, out_md) -> list[dict]:
    """Collect metrics JSONs into Table 1 (CSV with full precision, Markdown for reading).

    Rows are grouped by dataset (in the order they first appear in ``metrics_paths``), networks
    within a dataset in the fixed order nearest, gan, cgan, nerf, then others alphabetically.
    Columns: network, dataset, controllable, PSNR (dB, 1 decimal) and SSIM (3 decimals) for
    train / interpolation / extrapolation; "–" (empty in the CSV) for a split without images.
    Two files for the same (network, dataset) raise DataError.

    Returns:
        the rows as dicts keyed by the CSV columns.
    """
    entries = [(path, _load(path)) for path in metrics_paths]
    seen: dict[tuple[str, str], str] = {}
    for path, data in entries:
        key = (data["network"], data["dataset"])
        if key in seen:
            raise DataError(f"{seen[key]} and {path} both hold {key[0]} on {key[1]}; pass one metrics file per pair")
        seen[key] = str(path)
    datasets = list(dict.fromkeys(data["dataset"] for _, data in entries))
    entries.sort(key=lambda e: (datasets.index(e[1]["dataset"]), _network_key(e[1]["network"])))

    rows = []
    for _, data in entries:
        row = {"network": data["network"], "dataset": data["dataset"], "controllable": controllability(data)}
        for metric in ("psnr", "ssim"):
            for split in SPLITS:
                row[f"{metric}_{split}"] = data["splits"][split][metric] if data["splits"][split]["n"] else None
        for split in SPLITS:
            row[f"n_{split}"] = data["splits"][split]["n"]
        rows.append(row)

    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=CSV_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows({k: ("" if v is None else v) for k, v in row.items()} for row in rows)
    write_text_atomic(out_csv, buf.getvalue())

    samples = sorted({d["samples"] for _, d in entries if not d["controllable"] and d.get("samples")})
    best_of = f"best of {', '.join(map(str, samples))}" if samples else "best of N"
    lines = [
        "**Table 1.** Mean PSNR (dB, data range 1, capped at 100 dB) and SSIM per split; predicted and "
        "measured images are both divided by the maximum of the measured dataset (one scale per dataset, so "
        "intensity errors count). A network that is not controllable by the sun position is scored against "
        f"its {best_of} samples per image (the sample with the best PSNR): an optimistic upper bound. "
        f"{DASH} = split without images.",
        "",
        "| network | dataset | controllable | " + " | ".join(f"PSNR {SPLIT_LABELS[s]}" for s in SPLITS) + " | "
        + " | ".join(f"SSIM {SPLIT_LABELS[s]}" for s in SPLITS) + " |",
        "|---|---|---|" + "---:|" * (2 * len(SPLITS)),
    ]
    for row in rows:
        cells = [row["network"], row["dataset"], row["controllable"],
                 *(_fmt(row[f"psnr_{s}"], 1) for s in SPLITS), *(_fmt(row[f"ssim_{s}"], 3) for s in SPLITS)]
        lines.append("| " + " | ".join(cells) + " |")
    write_text_atomic(out_md, "\n".join(lines) + "\n")
    return rows

