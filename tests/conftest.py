"""Fixtures shared by the test folders."""

import pytest
import torch

from helioflow.models.training import train
from helioflow.physics.heliostat import Heliostat, ideal_heliostat


class Stopped(Exception):
    """Stands for a killed training job."""


@pytest.fixture
def train_stopped_after():
    """`train(model, data, loop, checkpoint, steps_done)`: the training loop, stopped (as by a kill)
    once `steps_done` steps are done; what it leaves is the checkpoint it wrote by then."""

    def run(model, data, loop, checkpoint, steps_done: int) -> None:
        step = model.training_step
        calls = iter(range(steps_done + 1))

        def counted(*args, **kwargs):
            if next(calls) == steps_done:
                raise Stopped
            return step(*args, **kwargs)

        model.training_step = counted
        with pytest.raises(Stopped):
            train(model, data, loop, checkpoint, progress=False)

    return run


def make_heliostat(rows=2, cols=2, width=1.0, height=1.0, gap=0.02, focal=None, canting=None,
                   position=(0.0, 0.0, 0.0), mount="az_el", n_control=6, dtype=torch.float64) -> Heliostat:
    """An ideal heliostat (physics.heliostat.ideal_heliostat) with the tests' defaults: 2 x 2 facets
    of 1 m, float64, at the origin."""
    return ideal_heliostat(rows, cols, width, height, gap, position, mount, canting, focal, n_control, dtype)
