"""The real heliostats' leave-one-out table of docs/results.md, from a run of
workflow/variants/paint_heliostats.yaml:

    snakemake -j2 all --configfile workflow/variants/paint_heliostats.yaml
    python scripts/experiments/real_heliostats.py [--results results/paint_heliostats] [--full DIR]

Per fold (held-out image): the held-out misplaced flux / centroid error (mrad) of the ideal
heliostat (`raytrace`: the sun and camera fitted), `drt` and `nearest`; the freedom drt took
(models/freedom.py); its fitted tracking against the fit on all of the target's images, in units of
the fold's sigma (|z| <= 2: the fold's tracking agrees with the calibration within its own
uncertainty); and the image's noise floor from the diagnosis of the whole dataset (what noise
leaves on a perfect model, diagnosis/<dataset>.json), in quadrature with the model's resolution
(diagnosis/diagnose.py compared_floor) as the bar "worse than the ideal beyond the noise".
`--full DIR`: a leave_one_out/ folder of the same run with `freedom: full` (everything fitted),
added as a column.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np

from helioflow.diagnosis.criteria import compared_floor
from helioflow.models.registry import load_model


def _rows(path: Path) -> dict[tuple[str, str], dict]:
    """{(id, network): CSV row} of a leave_one_out/<dataset>.csv."""
    with open(path, newline="") as f:
        return {(r["id"], r["network"]): r for r in csv.DictReader(f)}


def _floor(diagnosis: dict, azimuth: float, elevation: float) -> float | None:
    """The diagnosis' per-image noise floor of the image at that sun position (None if absent)."""
    per = diagnosis["signatures"]["per_image"]
    for a, e, floor in zip(per["azimuth_deg"], per["elevation_deg"], per["noise_floor"]):
        if abs(a - azimuth) < 1e-3 and abs(e - elevation) < 1e-3:  # the CSV keeps 4 decimals
            return float(floor)
    return None


def _tracking(path: Path) -> tuple[str, np.ndarray | None, np.ndarray | None]:
    """(freedom chosen, tracking (5,) mrad, its sigma (5,)) of a drt model file."""
    model, _ = load_model(path)
    chosen = model.freedom.chosen if model.freedom is not None else "full"
    tracking = model.fitted.tensors.get("tracking")
    u = model.fitted.uncertainty
    if tracking is None or u is None:
        return chosen, None, None
    names = [n for n in u.names if n.startswith("tracking.")]
    return chosen, tracking.detach().cpu().double().numpy(), np.array([u.sigma[u.index(n)] for n in names])


def _cell(r) -> str:
    return "–" if r is None else f"{float(r['misplaced_flux']):.3f} / {float(r['centroid_mrad']):.1f}"


def main() -> None:
    """Parse the command line and run the measurement the module docstring describes."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--results", default="results/paint_heliostats")
    parser.add_argument("--full", help="leave_one_out/ of a freedom: full run, added as a column")
    args = parser.parse_args()
    root = Path(args.results)
    print("| fold | ideal | drt | freedom | tracking \\|z\\| max | nearest | noise bar |"
          + (" drt, all fitted |" if args.full else ""))
    print("|---|---|---|---|---|---|---|" + ("---|" if args.full else ""))
    summary = []
    for table in sorted((root / "leave_one_out").glob("*.csv")):
        group = table.stem
        rows = _rows(table)
        full = _rows(Path(args.full) / table.name) if args.full else {}
        diagnosis_path = root / "diagnosis" / f"{group}.json"
        diagnosis = json.loads(diagnosis_path.read_text()) if diagnosis_path.exists() else None
        whole = _tracking(root / "models" / group / "drt.pt") if (root / "models" / group / "drt.pt").exists() else None
        for mid in dict.fromkeys(i for i, _ in rows):
            ideal, drt, near = (rows.get((mid, n)) for n in ("raytrace", "drt", "nearest"))
            floor = (None if diagnosis is None
                     else _floor(diagnosis, float(drt["azimuth_deg"]), float(drt["elevation_deg"])))
            bar = None if floor is None else float(compared_floor(floor, True))
            chosen, tracking, sigma = _tracking(root / "models" / f"{group}_loo_{mid}" / "drt.pt")
            z = "–"
            if tracking is not None and whole is not None and whole[1] is not None:
                z = f"{np.max(np.abs(tracking - whole[1]) / sigma):.1f}"
            print(f"| {group} {mid} | {_cell(ideal)} | {_cell(drt)} | {chosen} | {z} | {_cell(near)} | "
                  f"{'–' if bar is None else f'{bar:.3f}'} |"
                  + (f" {_cell(full.get((mid, 'drt')))} |" if args.full else ""))
            summary.append((float(ideal["misplaced_flux"]), float(drt["misplaced_flux"]), bar))
    ideal, drt, bar = (np.array([s[k] if s[k] is not None else np.nan for s in summary]) for k in range(3))
    worse = drt - ideal > np.nan_to_num(bar, nan=0.0)
    print(f"\n{len(summary)} folds: drt below the ideal on {int((drt < ideal).sum())}, worse beyond the noise bar on "
          f"{int(worse.sum())}; median misplaced flux drt {np.median(drt):.3f}, ideal {np.median(ideal):.3f}")


if __name__ == "__main__":
    main()
