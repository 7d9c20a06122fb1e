"""scipy.stats' normal and exponentially modified normal densities without the per-call overhead of
rv_continuous.pdf (argument parsing, support masks, argsreduce: about 9 in 10 of the time of
diagnosis/shared.py's `lower_envelope`, whose Nelder-Mead calls them some 20 000 times a Level),
for tests that fit many Levels (tests/diagnosis/test_shared.py).

Bit for bit scipy's own: the same arithmetic in the same order on the same private kernels
(`_pdf`), for the arguments where rv_continuous.pdf would compute them too (finite x, scale > 0,
shape > 0); any other call goes to scipy's pdf itself. `same_as_scipy` checks the equality.
"""

from types import SimpleNamespace

import numpy as np
from scipy import stats


class _Density:
    """`pdf(x, *shapes, loc, scale)` (all positional, as shared.py calls it) of the scipy distribution `dist`."""

    def __init__(self, dist):
        self.dist = dist

    def pdf(self, x, *args):
        *shapes, loc, scale = args
        x, loc, scale = np.asarray(x), np.asarray(loc), np.asarray(scale)
        shapes = [np.asarray(a) for a in shapes]
        z = np.asarray((x - loc) / scale, dtype=np.promote_types(x.dtype, np.float64))
        if z.ndim == 0 or not (np.isfinite(z).all() and (scale > 0).all() and all((a > 0).all() for a in shapes)):
            return self.dist.pdf(x, *shapes, loc, scale)  # the edge cases: scipy's own path
        z, *shapes, scale = np.broadcast_arrays(z, *shapes, scale)
        shape = z.shape
        out = self.dist._pdf(z.ravel(), *(a.ravel() for a in shapes)) / scale.ravel()
        return out.reshape(shape)


FAST_STATS = SimpleNamespace(norm=_Density(stats.norm), exponnorm=_Density(stats.exponnorm))


def same_as_scipy(seed: int = 0) -> bool:
    """Whether FAST_STATS' densities equal scipy's bit for bit on draws like those lower_envelope makes."""
    rng = np.random.default_rng(seed)
    y, sy = rng.uniform(1.0, 5.0, 30), rng.uniform(1e-9, 0.5, 30)
    for loc in (-3.0, 0.0, 2.25, 40.0):
        for k in (1e-6, 0.3, 7.0, 1e6):
            if not (np.array_equal(FAST_STATS.norm.pdf(y, loc, sy), stats.norm.pdf(y, loc, sy))
                    and np.array_equal(FAST_STATS.exponnorm.pdf(y, k / sy, loc, sy),
                                       stats.exponnorm.pdf(y, k / sy, loc, sy))):
                return False
    return True
