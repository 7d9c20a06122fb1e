"""How often the plant fit's shared level (diagnosis/shared.py `Level`) holds the true shared width
within its 95 % interval, against the plain inverse-variance sigma of the heliostats it kept, and
how far the median of the heliostats' values (the plant fit's estimator before the level) lies off.

Each trial draws n heliostats' own values of a shared width 1.5 (px): each with its own sigma
(uniform 0.03-0.06, as the plant fits report), a share `clean` of them without a widening of their
own, the rest widened by 0.05-0.5 (uniform; a slope error, a bump or canting).

Run: python scripts/experiments/shared_level_coverage.py [--trials 300]
"""

from __future__ import annotations

import argparse

import numpy as np

from helioflow.diagnosis.shared import Level

TRUE = 1.5


def main() -> None:
    """Parse the command line and run the measurement the module docstring describes."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=300)
    args = ap.parse_args()
    rng = np.random.default_rng(1)
    print("| heliostats | clean share | median - true: mean | level - true: mean | RMS | coverage: reported sigma "
          "| median sigma | coverage: kept heliostats' sigma alone | its median |")
    print("|---|---|---|---|---|---|---|---|---|")
    for n in (8, 30):
        for clean in (0.15, 0.33, 0.6):
            error, reported, plain, median = [], [], [], []
            for _ in range(args.trials):
                sigma = rng.uniform(0.03, 0.06, n)
                widened = rng.uniform(size=n) > clean
                values = TRUE + rng.normal(0.0, sigma) + widened * rng.uniform(0.05, 0.5, n)
                level = Level.of(values.tolist(), sigma.tolist())
                plain.append(level.kept_sigma)
                error.append(level.value - TRUE)
                median.append(np.median(values) - TRUE)
                reported.append(level.sigma)
            error, reported, plain = map(np.asarray, (error, reported, plain))
            rms = np.sqrt((error ** 2).mean())
            print(f"| {n} | {clean:.2f} | {np.mean(median):+.3f} | {error.mean():+.3f} | {rms:.3f} | "
                  f"{(np.abs(error) <= 1.96 * reported).mean():.2f} | {np.median(reported):.3f} | "
                  f"{(np.abs(error) <= 1.96 * plain).mean():.2f} | {np.median(plain):.3f} |")


if __name__ == "__main__":
    main()
