"""Fixtures shared by the test folders."""

import pytest

from helioflow.models.training import train


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
