"""The one training loop every network shares.

Seeded (each step's batch and randomness come from a generator seeded by (seed, step), so a run
resumed from a checkpoint repeats exactly what the uninterrupted run would have done), a tqdm
progress bar with the losses, a checkpoint every `checkpoint_every` steps that the next call
resumes from (only a call with the same model, config, seed, batch size, steps and data: the
checkpoint holds their `fingerprint`, so that a resumed run ends exactly where a clean run of the same
settings ends), one clear error on a NaN or exploding loss, and the training curve (CSV and PNG)
saved beside the model.
"""

from __future__ import annotations

import csv
import io
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path

import torch
from tqdm import tqdm

from helioflow.checks import check_ranges, check_types
from helioflow.errors import DataError, HelioflowError
from helioflow.io import fingerprint, load_torch, save_torch_atomic, write_text_atomic
from helioflow.models.base import SpotModel, TrainingData

log = logging.getLogger(__name__)


class TrainingDiverged(HelioflowError):
    """The loss became NaN, infinite or exploded."""


@dataclass(frozen=True)
class LoopConfig:
    """Settings of the loop itself (each network has its own config for the rest).

    Attributes:
        steps: optimisation steps.
        batch_size: training images per step.
        seed: seeds the model's initialisation and every step's randomness.
        checkpoint_every: steps between checkpoints.
        max_loss: a loss above this stops training as exploded.
    """

    steps: int = 1000
    batch_size: int = 16
    seed: int = 0
    checkpoint_every: int = 200
    max_loss: float = 1e6

    def __post_init__(self) -> None:
        check_types(self)
        check_ranges(self, at_least_one=("steps", "batch_size", "checkpoint_every"), positive=("max_loss",),
                     at_most={"steps": (1_000_000, "a million steps is days of training on a CPU"),
                              "batch_size": (4096, "images held per step")})


def step_generator(seed: int, step: int) -> torch.Generator:
    """The generator of one step: the same (seed, step) always gives the same randomness."""
    return torch.Generator().manual_seed(seed * 1_000_003 + step)


def train(
    model: SpotModel,
    data: TrainingData,
    loop: LoopConfig,
    checkpoint_path: str | os.PathLike,
    progress: bool = True,
) -> list[dict[str, float]]:
    """Train `model` on `data` for loop.steps steps, resuming from `checkpoint_path` if it exists.

    The checkpoint (model and optimizer states, the step reached, the curve so far) is written
    atomically every loop.checkpoint_every steps and at the end; delete it to start afresh. A
    checkpoint of another training (another model, config, seed, batch size, number of steps or data)
    is ignored and overwritten.

    Returns:
        The training curve: one dict per step with 'step' and the step's named losses.
    """
    checkpoint_path = Path(checkpoint_path)
    optimizers = model.configure_optimizers()
    start, curve = 0, []
    key = fingerprint(type(model).__name__, model.config, loop.seed, loop.batch_size, loop.steps, data)
    state = _checkpoint(checkpoint_path)
    if state is not None:
        if state.get("fingerprint") == key:
            model.load_state_dict(state["model"])
            for name, opt in optimizers.items():
                opt.load_state_dict(state["optimizers"][name])
            start, curve = state["step"], state["curve"]
            log.info("resuming the training from %s after step %d", checkpoint_path, start)
        else:
            log.info("ignoring %s: it holds another training (model, config, seed, batch size, steps or data)",
                     checkpoint_path)
    model.train()
    bar = tqdm(range(start, loop.steps), initial=start, total=loop.steps, disable=not progress,
               desc=f"train {model.name}", mininterval=2.0)
    for step in bar:
        generator = step_generator(loop.seed, step)
        index = torch.randint(0, len(data), (min(loop.batch_size, len(data)),), generator=generator)
        losses = model.training_step(data.batch(index), optimizers, generator)
        bad = {k: v for k, v in losses.items() if not math.isfinite(v) or abs(v) > loop.max_loss}
        if bad:
            raise TrainingDiverged(
                f"training {model.name} diverged at step {step}: {bad} (limit {loop.max_loss:g}); "
                "lower the learning rate or check the data; the last checkpoint is kept at "
                f"{checkpoint_path}"
            )
        curve.append({"step": step, **losses})
        bar.set_postfix({k: f"{v:.4g}" for k, v in losses.items()}, refresh=False)
        if (step + 1) % loop.checkpoint_every == 0 or step + 1 == loop.steps:
            save_checkpoint(checkpoint_path, key, model, optimizers, step + 1, curve)
    model.eval()
    return curve


def _checkpoint(path: Path) -> dict | None:
    """The state in a checkpoint file; None when there is none, or (with a warning) when it cannot be
    read: a checkpoint is only a shortcut, and the training starts afresh."""
    if not path.exists():
        return None
    try:
        return load_torch(path, "a training checkpoint")
    except DataError as exc:
        log.warning("ignoring the checkpoint: %s", exc)
        return None


def save_checkpoint(path: Path, key: str, model: SpotModel, optimizers: dict, step: int, curve: list[dict]) -> None:
    """Atomically write the resumable state of the training whose fingerprint is `key`."""
    save_torch_atomic(path, {"fingerprint": key, "model": model.state_dict(),
                             "optimizers": {k: o.state_dict() for k, o in optimizers.items()},
                             "step": step, "curve": curve})


def write_curve(curve: list[dict[str, float]], csv_path: str | os.PathLike, png_path: str | os.PathLike,
                title: str) -> None:
    """The training curve as CSV (step, losses...) and as a log-scale plot."""
    from helioflow.plotting import plt, save_figure

    keys = sorted({k for row in curve for k in row} - {"step"})
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=["step", *keys])
    writer.writeheader()
    writer.writerows(curve)
    write_text_atomic(csv_path, buf.getvalue())
    fig, ax = plt.subplots(figsize=(5, 3.2))
    for k in keys:
        steps = [row["step"] for row in curve if k in row]
        values = [abs(row[k]) for row in curve if k in row]
        ax.plot(steps, values, label=k, lw=0.8)
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("loss")
    ax.set_title(title, fontsize=9)
    if keys:
        ax.legend(fontsize=7)
    save_figure(fig, png_path)
