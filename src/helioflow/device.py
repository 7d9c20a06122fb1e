"""Which torch device a rule computes on (config `device`: cpu | cuda | auto).

Every rule that computes (trace, train, evaluate, diagnose, recovery, compose_field) resolves its
spec's device here. Random draws stay on the CPU (seeded torch.Generator objects) and move to the
device, so a seed draws the same numbers on every device.
"""

from __future__ import annotations

import torch


def resolve_device(device: str | torch.device) -> torch.device:
    """'auto' picks CUDA when it is there; otherwise the named device ('cpu', 'cuda', 'cuda:1')."""
    if str(device) == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)
