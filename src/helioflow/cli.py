"""`helioflow <step>`: one subcommand per pipeline rule, also usable by hand.

Each step takes its parameters either as the JSON the Snakefile passes (`--spec '{...}'`) or,
by hand, from a config file and a name (`--config config.yaml --name sanity_check`).
Errors in the user's input print one line, `helioflow <step>: error: ...`, and exit with 2.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys

import torch

from . import workflow
from .config import HeliostatSpec, load_config
from .errors import HelioflowError


def _spec(args, params) -> dict:
    if args.spec is not None:
        return json.loads(args.spec)
    if args.config is None or args.name is None:
        raise HelioflowError("give --spec JSON, or --config FILE and --name NAME")
    return params(load_config(args.config), args.name)


def cmd_surfaces(args) -> None:
    from .data.surfaces import true_heliostat, write_heliostat

    spec = HeliostatSpec.from_config(*_split_name(_spec(args, workflow.surfaces_params)))
    write_heliostat(args.output, true_heliostat(spec), spec)
    logging.info("wrote %s", args.output)


def _split_name(params: dict) -> tuple[str, dict]:
    params = dict(params)
    return params.pop("name"), params


def cmd_trace(args) -> None:
    from .data.synthetic import trace_dataset

    ds = trace_dataset(_spec(args, workflow.trace_params), args.heliostat, args.output)
    logging.info("wrote %s: %d images of %s", args.output, len(ds.images), ds.images.shape[1:])


def cmd_plot_dataset(args) -> None:
    from .evaluate.figures import plot_dataset_samples

    plot_dataset_samples(args.dataset, args.output, n=args.samples)
    logging.info("wrote %s", args.output)


def _with_spec(p: argparse.ArgumentParser) -> None:
    p.add_argument("--spec", help="the rule's parameters as JSON (what the Snakefile passes)")
    p.add_argument("--config", help="by hand: a config.yaml to take the parameters from")
    p.add_argument("--name", help="by hand: the heliostat / dataset name in that config")


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="helioflow", description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    ap.add_argument("-v", "--verbose", action="store_true")
    sub = ap.add_subparsers(dest="step", required=True)

    p = sub.add_parser("surfaces", help="write a heliostat's true geometry (ideal + seeded errors)")
    _with_spec(p)
    p.add_argument("--output", required=True, help="surfaces/{heliostat}.h5")
    p.set_defaults(func=cmd_surfaces)

    p = sub.add_parser("trace", help="raytrace a calibration dataset")
    _with_spec(p)
    p.add_argument("--heliostat", required=True, help="surfaces/{heliostat}.h5 from `surfaces`")
    p.add_argument("--output", required=True, help="datasets/{dataset}.h5")
    p.set_defaults(func=cmd_trace)

    p = sub.add_parser("plot-dataset", help="figure of sample images of a dataset")
    p.add_argument("--dataset", required=True, help="datasets/{dataset}.h5")
    p.add_argument("--samples", type=int, default=12, help="number of images shown")
    p.add_argument("--output", required=True, help="PNG file")
    p.set_defaults(func=cmd_plot_dataset)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    torch.set_num_threads(args.threads)
    try:
        args.func(args)
    except (HelioflowError, json.JSONDecodeError) as exc:
        print(f"helioflow {args.step}: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
