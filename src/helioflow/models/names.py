"""Model names as the workflow writes them: a network, or a network trained on fewer train images
(the data-efficiency runs). Imports nothing heavy: the Snakefile reads names while it builds the DAG."""

from __future__ import annotations

from helioflow.errors import ConfigError


def parse_model(model: str) -> tuple[str, int | None]:
    """'cgan' -> ('cgan', None); 'cgan-n25' -> ('cgan', 25): a network trained on 25 train images."""
    network, sep, count = model.partition("-n")
    if sep and not count.isdigit():
        raise ConfigError(f"model name {model!r}: expected <network> or <network>-n<train images>")
    return network, int(count) if sep else None
