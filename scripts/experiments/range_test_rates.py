"""How often the plant fit's slant-range test (diagnosis/shared.py `RangeTest`) reads the sun as
wider or narrower than told beyond RANGE_SIGNIFICANCE sigma: its false alarms where the sun is told
right and its power where it is not.

Each trial draws a plant of 30 heliostats at slant ranges uniform over 50-86 m (plant30's), on
Jülich's upper target over 64 pixels, a camera blur of 1.5 px and a sun of 2.51 mrad told `told`,
each heliostat's blur with its sigma (uniform 0.08-0.2 px, as the plant fits on plant30 report).
A share `clean` of the heliostats carries no widening of its own; the others an angular one (a
slope error, a canting, a bump: uniform over `own` mrad^2 of variance, so in pixels it grows with
slant range as the sun's does). The test's sigma is the line's (inverse-variance, inflated by its
chi^2 per degree of freedom) or, in the second pair of columns, the larger of it and the spread of
the line over the heliostats resampled (60 draws).

Run: python scripts/experiments/range_test_rates.py [--trials 60]   (about 2 min)
"""

from __future__ import annotations

import argparse
from types import SimpleNamespace

import numpy as np

from helioflow.diagnosis.shared import RANGE_SIGNIFICANCE, RangeTest, clipped_level

PIXEL_M = 8.625 / 64
TRUE_SUN, TRUE_BLUR = 2.51, 1.5
WORLDS = [  # (told sun mrad, clean share, own angular variance low, high mrad^2)
    (2.51, 0.07, 1, 8), (2.51, 0.33, 1, 8), (2.51, 0.67, 1, 8), (2.51, 0.07, 1, 16),
    (2.0, 0.9, 1, 8), (2.0, 0.67, 1, 8), (2.0, 0.33, 1, 8), (3.0, 0.33, 1, 8), (3.0, 0.07, 1, 8)]


def range_test(values: np.ndarray, sigmas: np.ndarray, ranges: np.ndarray) -> RangeTest:
    """The test on heliostats' blurs (n,) px with their sigmas and slant ranges (m), kept by the clipping."""
    _, kept = clipped_level(values, sigmas)
    level = SimpleNamespace(values=values.tolist(), sigmas=sigmas.tolist(), kept=kept.tolist())
    return RangeTest.of(level, ranges.tolist(), PIXEL_M)


def trial(seed: int, told: float, clean: float, low: float, high: float) -> tuple[float, float]:
    """One plant -> (z of the line's sigma, z of the larger of it and the bootstrap's)."""
    rng = np.random.default_rng(seed)
    ranges, sigmas = rng.uniform(50.0, 86.0, 30), rng.uniform(0.08, 0.2, 30)
    own = np.where(rng.uniform(size=30) < clean, 0.0, rng.uniform(low, high, 30))
    x = (ranges * 1e-3 / PIXEL_M) ** 2
    values = np.sqrt(TRUE_BLUR ** 2 + (TRUE_SUN ** 2 - told ** 2 + own) * x) + rng.normal(0.0, sigmas)
    test = range_test(values, sigmas, ranges)
    draws = rng.integers(0, 30, (60, 30))
    spread = float(np.std([range_test(values[d], sigmas[d], ranges[d]).deficit_mrad2 for d in draws]))
    return test.deficit_mrad2 / test.sigma_mrad2, test.deficit_mrad2 / max(test.sigma_mrad2, spread)


def main() -> None:
    """Parse the command line and print the rates the module docstring describes."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=60)
    args = ap.parse_args()
    k = RANGE_SIGNIFICANCE
    print("| sun told (true 2.51 mrad) | clean share | own widening (mrad^2) | line's sigma: wider | narrower "
          "| with the bootstrap: wider | narrower |")
    print("|---|---|---|---|---|---|---|")
    for told, clean, low, high in WORLDS:
        z = np.array([trial(s, told, clean, low, high) for s in range(args.trials)])
        rates = [(z[:, i] > k).mean() for i in (0, 1)], [(z[:, i] < -k).mean() for i in (0, 1)]
        print(f"| {told} | {clean:.2f} | {low}-{high} | {rates[0][0]:.2f} | {rates[1][0]:.2f} | {rates[0][1]:.2f} "
              f"| {rates[1][1]:.2f} |", flush=True)


if __name__ == "__main__":
    main()
