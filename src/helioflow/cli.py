"""`helioflow <step>`: one subcommand per pipeline rule, also usable by hand.

Each step takes its parameters either as the JSON the Snakefile passes (`--spec '{...}'`) or,
by hand, from a config file and a name (`--config config.yaml --name sanity_check`).
Errors in the user's input print one line, `helioflow <step>: error: ...`, and exit with 2.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from collections import Counter
from pathlib import Path

from helioflow import workflow
from helioflow.errors import HelioflowError


def read_spec(text: str):
    """A rule's parameters: JSON text, or '@path' for a JSON file (what a rule whose parameters grow
    with the field passes: no command-line length limit)."""
    if not text.startswith("@"):
        return json.loads(text)
    try:
        return json.loads(Path(text[1:]).read_text())
    except OSError as exc:
        raise HelioflowError(f"{text[1:]}: cannot read the rule's parameters: {exc.strerror}") from None


def _spec(args, params) -> dict:
    if args.spec is not None:
        return read_spec(args.spec)
    if args.config is None or args.name is None:
        raise HelioflowError("give --spec JSON, or --config FILE and --name NAME")
    from helioflow.config import load_config

    return params(workflow.expand_config(load_config(args.config)), args.name)


def cmd_recovery(args) -> None:
    """`helioflow recovery`: what a fitted drt model recovered of a synthetic heliostat's true errors."""
    from helioflow.scoring.recovery import recovery, write_recovery

    if args.output is None:
        print(json.dumps(recovery(args.model, args.heliostat, args.dataset, args.device), indent=1))
    else:
        write_recovery(args.model, args.heliostat, args.dataset, args.output, args.device)


def cmd_fitted_heliostat(args) -> None:
    """`helioflow fitted-heliostat`: the heliostat a drt fit found, as JSON (and a figure)."""
    from helioflow.scoring.fitted_heliostat import fitted_heliostat, write_fitted_heliostat

    step = {} if args.grid_step_m is None else {"grid_step_m": args.grid_step_m}
    if args.output is None:
        print(json.dumps(fitted_heliostat(args.model, **step), indent=1))
    else:
        write_fitted_heliostat(args.model, args.output, args.figure, **step)


def cmd_batch(args) -> None:
    """`helioflow batch`: several steps in one process, each with its own log."""
    from helioflow.batch import run_batch

    run_batch(read_spec(args.commands), parser().parse_args)


def cmd_plan_measurements(args) -> None:
    """`helioflow plan-measurements`: the sun positions that shrink a fitted model's uncertainty most."""
    from helioflow.models.planning import plan_measurements

    spec = _spec(args, workflow.plan_params)  # --name: the dataset's name in the config
    result = plan_measurements(args.model, args.dataset, spec["settings"], args.output, spec.get("device", "cpu"))
    if args.output is None:
        print(json.dumps(result, indent=1))


def cmd_surfaces(args) -> None:
    """`helioflow surfaces`: write a heliostat's true geometry (ideal + seeded errors)."""
    from helioflow.data.surfaces import HeliostatSpec, true_heliostat, write_heliostat

    spec = HeliostatSpec.from_config(*_split_name(_spec(args, workflow.surfaces_params)))
    write_heliostat(args.output, true_heliostat(spec), spec)
    logging.info("wrote %s", args.output)


def _split_name(params: dict) -> tuple[str, dict]:
    params = dict(params)
    return params.pop("name"), params


def cmd_trace(args) -> None:
    """`helioflow trace`: raytrace a calibration dataset."""
    from helioflow.data.synthetic import trace_dataset

    ds = trace_dataset(_spec(args, workflow.trace_params), args.heliostat, args.output)
    logging.info("wrote %s: %d images of %s", args.output, len(ds.images), ds.images.shape[1:])


def cmd_import_paint(args) -> None:
    """`helioflow import-paint`: a PAINT heliostat's dataset and/or ideal geometry."""
    from helioflow.data.paint import CENTERED_DEFAULT, import_paint

    if args.paint_dir is not None or args.heliostat is not None:
        if args.paint_dir is None or args.heliostat is None:
            raise HelioflowError("by hand, give both --paint-dir and --heliostat")
        spec = {"paint_dir": args.paint_dir, "heliostat": args.heliostat, "resolution": args.resolution,
                "holdout": args.holdout, "targets": args.targets, "dni_w_m2": args.dni,
                "centered": args.centered or CENTERED_DEFAULT}
    else:
        spec = _spec(args, workflow.import_paint_params)
    if args.output is None and args.heliostat_output is None:
        raise HelioflowError("give --output (the dataset), --heliostat-output (the geometry) or both")
    ds = import_paint(spec["paint_dir"], spec["heliostat"], args.output, args.heliostat_output,
                      resolution=tuple(spec.get("resolution") or (64, 64)), holdout=spec.get("holdout") or [],
                      targets=spec.get("targets"), dataset=spec.get("dataset"), dni_w_m2=spec.get("dni_w_m2", 1000.0),
                      centered=spec.get("centered", CENTERED_DEFAULT))
    if ds is not None:
        labels = dict(Counter(ds.split.tolist()))
        logging.info("wrote %s: %d images of %s from %s/%s (%d centered, placed; splits %s; targets %s)", args.output,
                     len(ds.images), ds.images.shape[1:], spec["paint_dir"], spec["heliostat"],
                     int(ds.extras["centered"].sum()), labels, ", ".join(ds.attrs["targets"]))
    if args.heliostat_output is not None:
        logging.info("wrote %s: the ideal geometry of %s", args.heliostat_output, spec["heliostat"])


def cmd_import_images(args) -> None:
    """`helioflow import-images`: one's own calibration images (a folder and a CSV) as a dataset."""
    from helioflow.data.images import import_images

    if args.output is None and args.heliostat_output is None:
        raise HelioflowError("give --output (the dataset), --heliostat-output (the geometry) or both")
    spec = _spec(args, workflow.import_images_params)  # by hand: --name is the dataset's name
    ds = import_images(spec, args.output, args.heliostat_output)
    if ds is not None:
        labels = dict(Counter(ds.split.tolist()))
        logging.info("wrote %s: %d images of %s from %s (%s x %s pixels; splits %s; sun from %s)", args.output,
                     len(ds.images), ds.images.shape[1:], spec["csv"], *ds.attrs["source_image_shape"][::-1], labels,
                     ds.attrs["sun_from"])
    if args.heliostat_output is not None:
        logging.info("wrote %s: the ideal geometry of %s", args.heliostat_output, spec["heliostat"])


def cmd_paint_centroids(args) -> None:
    """`helioflow paint-centroids`: measured vs ideal spot centroid (mrad) per PAINT image."""
    from helioflow.scoring.paint_centroids import centroid_check, format_table, write_centroid_check

    rows = centroid_check(args.dataset, args.heliostat)
    print(format_table(rows))
    if args.output is not None:
        write_centroid_check(rows, args.output)
        logging.info("wrote %s", args.output)


def cmd_plot_dataset(args) -> None:
    """`helioflow plot-dataset`: a figure of sample images of a dataset."""
    from helioflow.data.figures import plot_dataset_samples

    plot_dataset_samples(args.dataset, args.output, n=args.samples)
    logging.info("wrote %s", args.output)


def cmd_train(args) -> None:
    """`helioflow train`: train a network on a dataset's train split."""
    from helioflow.models.registry import train_network

    dataset = os.path.splitext(os.path.basename(args.dataset))[0]
    spec = _spec(args, lambda config, model: workflow.train_params(config, dataset, model))
    if spec.get("shared"):  # a plant's heliostat: the shared effects at the plant fit's values
        from helioflow.diagnosis.shared import with_plant

        spec["settings"]["effects"] = with_plant(spec["settings"]["effects"], spec["shared"])
    train_network(spec["network"], spec["settings"], args.dataset, args.output, args.curve, args.curve_figure,
                  seed=spec["seed"], train_images=spec["train_images"], device=spec.get("device", "cpu"))


DIAGNOSIS_FIGURES = ("signatures", "ranking", "residuals", "location", "ledger-figure")


def cmd_diagnose(args) -> None:
    """`helioflow diagnose`: which physical effect the model lacks, from a dataset's measurements."""
    from helioflow.diagnosis.diagnose import diagnose_dataset

    spec = _spec(args, workflow.diagnose_params)  # --name: the dataset's name in the config
    stem = os.path.splitext(args.output)[0]
    figures = {name.removesuffix("-figure"): getattr(args, name.replace("-", "_")) or f"{stem}_{name}.png"
               for name in DIAGNOSIS_FIGURES}
    shared = spec.get("shared")  # a plant's heliostat: the shared effects at the plant fit's values
    if shared:
        from helioflow.diagnosis.shared import with_plant

        spec["effects"] = with_plant(spec["effects"], shared)
    diagnose_dataset(args.dataset, args.heliostat, spec["effects"], spec["settings"], args.output, figures,
                     args.ledger or f"{stem}_ledger.json", spec.get("device", "cpu"), (shared or {}).get("plant", ""))


def cmd_evaluate(args) -> None:
    """`helioflow evaluate`: score a model on every split of a dataset."""
    from helioflow.schema import with_defaults
    from helioflow.scoring.evaluation import evaluate_model

    spec = with_defaults(read_spec(args.spec) if args.spec else {}, "evaluation")  # the schema's gan_samples if unset
    result = evaluate_model(args.model, args.dataset, args.metrics, args.per_image, args.grid, args.psnr,
                            gan_samples=spec["gan_samples"], device=spec.get("device", "cpu"))
    for split, m in result["splits"].items():
        logging.info("%s: %s", split, m)


def cmd_compose_field(args) -> None:
    """`helioflow compose-field`: truth, ideal and hybrid flux maps of the field on the receiver."""
    from helioflow.config import load_config
    from helioflow.field.compose import compose_field

    if args.spec is not None:
        spec = read_spec(args.spec)
        inputs = {k: spec.pop(k) for k in ("models", "datasets") if k in spec}
    elif args.config is not None:
        config = workflow.expand_config(load_config(args.config))
        if not config.get("field"):
            raise HelioflowError(f"{args.config} has no field section")
        spec, inputs = workflow.compose_field_params(config), workflow.compose_field_inputs(config)
    else:
        raise HelioflowError("give --spec JSON or --config FILE")
    models = args.models if args.models is not None else inputs.get("models", [])
    datasets = args.datasets if args.datasets is not None else inputs.get("datasets", [])
    metrics = compose_field(spec, models, datasets, args.flux, args.figure, args.metrics)
    for name, m in metrics["summary"].items():
        logging.info("%s: %s", name, {k: round(v, 4) for k, v in m.items()} if "flux_accuracy" in m else m)
    logging.info("wrote %s, %s and %s in %.1f s", args.flux, args.figure, args.metrics, metrics["seconds"])


def cmd_optimise_aim(args) -> None:
    """`helioflow optimise-aim`: aim points chosen on the ideal, hybrid and true field, judged on the truth."""
    from helioflow.field.aiming import optimise_aim

    spec = read_spec(args.spec)
    result = optimise_aim(spec, spec.pop("models", []), spec.pop("datasets", []), args.metrics, args.figure)
    for point, row in result["design_points"].items():
        logging.info("%s: %s", point, {s: round(m["truth_peak_over_limit"], 3) for s, m in row.items()})
    logging.info("wrote %s and %s in %.1f s", args.metrics, args.figure, result["seconds"])


def _metric_paths(paths: list[str]) -> list[str]:
    """--metrics: the files, or one @FILE of a spec with the list under "metrics" (workflow.rule_spec)."""
    return read_spec(paths[0])["metrics"] if len(paths) == 1 and paths[0].startswith("@") else paths


def cmd_table(args) -> None:
    """`helioflow table`: Table 1 from metrics files."""
    from helioflow.scoring.table import build_table

    build_table(_metric_paths(args.metrics), args.csv, args.markdown)
    logging.info("wrote %s and %s", args.csv, args.markdown)


def cmd_data_efficiency(args) -> None:
    """`helioflow data-efficiency`: PSNR against the number of training images."""
    from helioflow.scoring.efficiency import plot_data_efficiency

    plot_data_efficiency(_metric_paths(args.metrics), args.figure, args.csv)
    logging.info("wrote %s and %s", args.figure, args.csv)


def cmd_leave_one_out(args) -> None:
    """`helioflow leave-one-out`: held-out scores and pictures of a leave-one-out run on real images."""
    from helioflow.scoring.leave_one_out import leave_one_out

    inputs = json.loads(args.inputs)
    by_network = {kind: {k.removeprefix(f"{kind}_"): v for k, v in inputs.items() if k.startswith(f"{kind}_")}
                  for kind in ("model", "metrics")}
    leave_one_out(inputs["datasets"], by_network["model"], by_network["metrics"], args.csv, args.figure)
    logging.info("wrote %s and %s", args.csv, args.figure)


def cmd_plant_table(args) -> None:
    """`helioflow plant-table`: one row per heliostat of the plant entries."""
    from helioflow.scoring.plant import write_plant_table

    if args.spec is not None:
        spec = read_spec(args.spec)
    elif args.config is not None:
        from helioflow.config import load_config

        spec = workflow.plant_table_spec(workflow.expand_config(load_config(args.config)))
    else:
        raise HelioflowError("give --spec JSON or @FILE, or --config FILE")
    rows = write_plant_table(spec, args.csv)
    if args.plan is not None:
        from helioflow.scoring.plant_figure import plot_plant_plan

        plot_plant_plan(args.plan, rows, spec["pointing_limit_mrad"])
    logging.info("wrote %s (%d heliostats)", args.csv, len(rows))


def cmd_plant_shared(args) -> None:
    """`helioflow plant-shared`: what a plant's heliostats share, fitted once across them."""
    from helioflow.diagnosis.shared import plant_shared

    out = plant_shared(read_spec(args.spec), args.output)
    for plant, entry in out.items():
        logging.info("%s: %s", plant, entry["verdict"])


def cmd_plant_flux(args) -> None:
    """`helioflow plant-flux`: a plant's flux maps on its receiver."""
    from helioflow.field.plant import compose_plant

    spec = read_spec(args.spec)
    if args.plant not in spec:
        raise HelioflowError(f"--plant {args.plant}: no such plant entry in the spec; entries: "
                             f"{', '.join(spec) or 'none'}")
    summary = compose_plant(spec[args.plant], args.flux, args.figure, args.metrics)["summary"]
    logging.info("%s: ideal against calibrated flux accuracy %.3f, mean spot shift %s m", args.plant,
                 summary["ideal_against_calibrated"]["flux_accuracy"], summary["mean_spot_shift_m"])


def cmd_plant_aim(args) -> None:
    """`helioflow plant-aim`: a plant's aim points under its receiver's flux limit."""
    from helioflow.field.plant_aim import optimise_plant_aim

    spec = read_spec(args.spec)
    if args.plant not in spec:
        raise HelioflowError(f"--plant {args.plant}: no such plant entry in the spec; entries: "
                             f"{', '.join(spec) or 'none'}")
    if not spec[args.plant]["settings"].get("optimise_aim"):
        raise HelioflowError(f"--plant {args.plant}: its spec has no settings.optimise_aim (config "
                             "plant.flux.optimise_aim: {limit_kw_m2: ...})")
    result = optimise_plant_aim(spec[args.plant], args.output, args.figure)
    for point, row in result["design_points"].items():
        logging.info("%s %s: calibrated peak / limit %s", args.plant, point,
                     ", ".join(f"{s} {m['calibrated_peak_over_limit']:.3f}" for s, m in row.items()))


def cmd_report(args) -> None:
    """`helioflow report`: the self-contained HTML report of an experiment."""
    from helioflow.report.page import write_report

    write_report(args.output, read_spec(args.inputs), args.benchmarks, args.experiment)
    logging.info("wrote %s", args.output)


def _with_spec(p: argparse.ArgumentParser) -> None:
    """The parameters' sources, after a subcommand's own options: a config file and a name (by hand),
    or the rule's JSON spec (what the Snakefile passes)."""
    p.add_argument("--config", help="a config.yaml to take the parameters from")
    p.add_argument("--name", help="the heliostat / dataset / model name in that config")
    p.add_argument("--spec", help="instead of --config and --name: the rule's parameters as JSON, or @FILE "
                                  "(what the Snakefile passes)")



def _plant_flux_spec_arguments(p: argparse.ArgumentParser) -> None:
    """--spec and --plant of the commands that read rule plant_flux's spec (plant-flux, plant-aim)."""
    p.add_argument("--spec", required=True, help="the rule's parameters as JSON, or @FILE (what the Snakefile "
                                                 "passes: specs/plant_flux.json)")
    p.add_argument("--plant", required=True, help="the plant entry (a key of the spec)")

def parser() -> argparse.ArgumentParser:
    """The `helioflow` command line: one subcommand per step."""
    ap = argparse.ArgumentParser(prog="helioflow", description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    ap.add_argument("-v", "--verbose", action="store_true")
    sub = ap.add_subparsers(dest="step", required=True)

    p = sub.add_parser("surfaces", help="write a heliostat's true geometry (ideal + seeded errors)")
    p.add_argument("--output", required=True, help="surfaces/{heliostat}.h5")
    _with_spec(p)
    p.set_defaults(func=cmd_surfaces)

    p = sub.add_parser("trace", help="raytrace a calibration dataset")
    p.add_argument("--heliostat", required=True, help="surfaces/{heliostat}.h5 from `surfaces`")
    p.add_argument("--output", required=True, help="datasets/{dataset}.h5")
    _with_spec(p)
    p.set_defaults(func=cmd_trace)

    p = sub.add_parser("import-paint", help="import a PAINT heliostat: dataset and/or ideal geometry")
    p.add_argument("--paint-dir", help="by hand: the PAINT directory (tower-measurements.json, heliostat folders)")
    p.add_argument("--heliostat", help="by hand: the heliostat folder, e.g. AA39")
    p.add_argument("--resolution", type=int, nargs=2, default=[64, 64], metavar=("ROWS", "COLS"),
                   help="by hand: image size of the dataset (default 64 64)")
    p.add_argument("--holdout", nargs="*", default=[], metavar="ID", help="by hand: measurement ids held out")
    p.add_argument("--targets", nargs="+", metavar="NAME", help="by hand: only measurements on these targets")
    p.add_argument("--dni", type=float, default=1000.0, metavar="W_M2",
                   help="by hand: nominal DNI of the dataset's attribute dni_w_m2 (default 1000)")
    p.add_argument("--centered", metavar="place|skip",
                   help="by hand: place the measurements with only a centered image by their UTIS centroid "
                        "(default) or skip them")
    p.add_argument("--output", help="datasets/{dataset}.h5")
    p.add_argument("--heliostat-output", help="surfaces/{heliostat}.h5: the ideal heliostat geometry")
    _with_spec(p)
    p.set_defaults(func=cmd_import_paint)

    p = sub.add_parser("import-images", help="import one's own calibration images (a folder and a CSV): dataset "
                       "and/or ideal geometry")
    p.add_argument("--output", help="datasets/{dataset}.h5")
    p.add_argument("--heliostat-output", help="surfaces/{dataset}.h5: the heliostat's ideal geometry")
    _with_spec(p)
    p.set_defaults(func=cmd_import_images)

    p = sub.add_parser("paint-centroids", help="measured vs ideal spot centroid (mrad) per PAINT image")
    p.add_argument("--dataset", required=True, help="datasets/{dataset}.h5 from import-paint")
    p.add_argument("--heliostat", required=True, help="surfaces/{heliostat}.h5 from import-paint")
    p.add_argument("--output", help="JSON file of the per-image numbers")
    p.set_defaults(func=cmd_paint_centroids)

    p = sub.add_parser("train", help="train a network on a dataset's train split")
    p.add_argument("--dataset", required=True, help="datasets/{dataset}.h5")
    p.add_argument("--output", required=True, help="models/{dataset}/{model}.pt")
    p.add_argument("--curve", required=True, help="training curve CSV")
    p.add_argument("--curve-figure", required=True, help="training curve PNG")
    _with_spec(p)
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("diagnose", help="which physical effect the model lacks, from a dataset's measurements")
    p.add_argument("--dataset", required=True, help="datasets/{dataset}.h5")
    p.add_argument("--heliostat", required=True, help="surfaces/{heliostat}.h5 (its design geometry is traced)")
    p.add_argument("--output", required=True, help="diagnosis/{dataset}.json")
    p.add_argument("--ledger", help="the error ledger JSON kept across runs (default: <output>_ledger.json)")
    for name in DIAGNOSIS_FIGURES:
        p.add_argument(f"--{name}", help=f"{name} figure (default: <output>_{name}.png)")
    _with_spec(p)
    p.set_defaults(func=cmd_diagnose)

    p = sub.add_parser("evaluate", help="score a model on every split of a dataset")
    p.add_argument("--model", required=True, help="models/<dataset>/<model>.pt")
    p.add_argument("--dataset", required=True, help="datasets/<dataset>.h5")
    p.add_argument("--metrics", required=True, help="JSON of the scores per split")
    p.add_argument("--per-image", required=True, help="CSV of the scores per image")
    p.add_argument("--grid", required=True, help="PNG: measured / predicted / difference")
    p.add_argument("--psnr", required=True, help="PNG: PSNR against sun position")
    p.add_argument("--spec", help="settings as JSON, e.g. '{\"gan_samples\": 64, \"device\": \"cuda\"}'")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("compose-field", help="truth, ideal and hybrid flux maps of the field on the receiver")
    p.add_argument("--flux", required=True, help="field/flux.h5")
    p.add_argument("--figure", required=True, help="field/flux.png")
    p.add_argument("--metrics", required=True, help="field/metrics.json")
    p.add_argument("--config", help="a config.yaml with a field section")
    p.add_argument("--models", nargs="*", help="models/<heliostat>/<network>.pt of the measured heliostats "
                   "(default with --config: under results/<experiment>/)")
    p.add_argument("--datasets", nargs="*",
                   help="datasets/<heliostat>.h5 of the measured heliostats, in the same order")
    p.add_argument("--spec", help="instead of --config: the rule's parameters as JSON, or @FILE of them with the "
                                  "lists models and datasets (what the Snakefile passes: specs/compose_field.json)")
    p.set_defaults(func=cmd_compose_field)

    p = sub.add_parser("optimise-aim", help="aim points under the receiver's flux limit, judged on the true field")
    p.add_argument("--figure", required=True, help="field/aim.png")
    p.add_argument("--metrics", required=True, help="field/aim.json")
    p.add_argument("--spec", required=True, help="the rule's parameters as JSON, or @FILE of them with the lists "
                   "models and datasets (what the Snakefile passes: specs/optimise_aim.json)")
    p.set_defaults(func=cmd_optimise_aim)

    p = sub.add_parser("table", help="Table 1 from metrics files")
    p.add_argument("--metrics", nargs="+", required=True, help="metrics/<dataset>/<model>.json files, or @FILE: "
                   "a JSON object whose 'metrics' lists them (what the Snakefile passes: specs/table.json)")
    p.add_argument("--csv", required=True)
    p.add_argument("--markdown", required=True)
    p.set_defaults(func=cmd_table)

    p = sub.add_parser("data-efficiency", help="PSNR against the number of training images")
    p.add_argument("--metrics", nargs="+", required=True, help="metrics files, or @FILE (specs/data_efficiency.json)")
    p.add_argument("--figure", required=True)
    p.add_argument("--csv", required=True)
    p.set_defaults(func=cmd_data_efficiency)

    p = sub.add_parser("plot-dataset", help="figure of sample images of a dataset")
    p.add_argument("--dataset", required=True, help="datasets/{dataset}.h5")
    p.add_argument("--samples", type=int, default=12, help="number of images shown")
    p.add_argument("--output", required=True, help="PNG file")
    p.set_defaults(func=cmd_plot_dataset)

    p = sub.add_parser("leave-one-out", help="held-out scores and pictures of a leave-one-out run on real images")
    p.add_argument("--inputs", required=True, help="JSON: datasets, model_<network> and metrics_<network> file "
                   "lists, one per fold (what helioflow.workflow.leave_one_out_inputs gives)")
    p.add_argument("--csv", required=True, help="leave_one_out/<dataset>.csv: per held-out image and network")
    p.add_argument("--figure", required=True, help="PNG: measured and predicted held-out images")
    p.set_defaults(func=cmd_leave_one_out)

    p = sub.add_parser("plant-table", help="one row per heliostat of the plant entries: errors, named effects, "
                       "pointing error with its sigma, canting, surface, flags")
    p.add_argument("--spec", help="the rule's parameters as JSON, or @FILE (what the Snakefile passes: "
                                  "specs/plant_table.json)")
    p.add_argument("--config", help="instead of --spec: the config file (its plant entries and `plant` section)")
    p.add_argument("--csv", required=True, help="plant/heliostats.csv")
    p.add_argument("--plan", help="plant/plan.png: the plant's plan coloured by pointing error (optional)")
    p.set_defaults(func=cmd_plant_table)

    p = sub.add_parser("plant-flux", help="a plant's flux maps on its receiver: calibrated heliostats as fitted, "
                                          "the rest ideal")
    _plant_flux_spec_arguments(p)
    p.add_argument("--flux", required=True, help="plant/flux/<plant>.h5")
    p.add_argument("--figure", required=True, help="plant/flux/<plant>.png")
    p.add_argument("--metrics", required=True, help="plant/flux/<plant>.json")
    p.set_defaults(func=cmd_plant_flux)

    p = sub.add_parser("plant-aim", help="a plant's aim points under its receiver's flux limit, chosen on the "
                                         "design and on the calibrated heliostats")
    _plant_flux_spec_arguments(p)
    p.add_argument("--output", required=True, help="plant/aim/<plant>.json")
    p.add_argument("--figure", required=True, help="plant/aim/<plant>.png")
    p.set_defaults(func=cmd_plant_aim)

    p = sub.add_parser("plant-shared", help="what a plant's heliostats share (the sun, the camera), fitted once "
                                            "across them")
    p.add_argument("--spec", required=True, help="the rule's parameters as JSON, or @FILE (what the Snakefile "
                                                 "passes: specs/plant_shared.json)")
    p.add_argument("--output", required=True, help="plant/shared.json")
    p.set_defaults(func=cmd_plant_shared)

    p = sub.add_parser("recovery", help="what a fitted drt model recovered of a synthetic heliostat's true errors")
    p.add_argument("--model", required=True, help="models/<dataset>/drt.pt")
    p.add_argument("--heliostat", required=True, help="surfaces/<heliostat>.h5 the dataset was traced from")
    p.add_argument("--dataset", required=True, help="datasets/<dataset>.h5")
    p.add_argument("--output", help="recovery/<dataset>.json (default: print the JSON)")
    p.add_argument("--device", default="cpu", choices=("cpu", "cuda", "auto"), help="where the model predicts")
    p.set_defaults(func=cmd_recovery)

    p = sub.add_parser("fitted-heliostat", help="the heliostat a drt fit found (surface deviation on a grid, slope "
                                                "error, canting, tracking, each with sigma), as JSON")
    p.add_argument("--model", required=True, help="models/<dataset>/drt.pt")
    p.add_argument("--output", help="heliostats/<dataset>.json (default: print the JSON)")
    p.add_argument("--figure", help="heliostats/<dataset>.png: the surface's deviation and sigma (with --output)")
    p.add_argument("--grid-step-m", type=float, help="spacing of the surface grid (m; default 0.05)")
    p.set_defaults(func=cmd_fitted_heliostat)

    p = sub.add_parser("plan-measurements", help="the next calibration images to take: the sun positions that "
                                                 "shrink a fitted physics model's uncertainty most")
    p.add_argument("--model", required=True, help="models/<dataset>/drt.pt (or raytrace.pt)")
    p.add_argument("--dataset", required=True, help="datasets/<dataset>.h5 (its site, where it records one)")
    p.add_argument("--output", help="plan/<dataset>.json (default: print the JSON)")
    _with_spec(p)
    p.set_defaults(func=cmd_plan_measurements)

    p = sub.add_parser("batch", help="several steps in one process, each with its own log (a plant's group of "
                                     "heliostats, config plant.group_size)")
    p.add_argument("--commands", required=True, help="JSON list of {argv: the step's arguments, log: its log file}, "
                                                     "or @FILE of it (what helioflow.batch.batch_job gives)")
    p.set_defaults(func=cmd_batch)

    p = sub.add_parser("report", help="the self-contained HTML report of an experiment")
    p.add_argument("--inputs", required=True,
                   help="JSON: report section -> list of files (what helioflow.workflow.report_inputs gives), "
                        "or @FILE of it (what the Snakefile passes: specs/report.json)")
    p.add_argument("--benchmarks", help="the experiment's benchmarks/ folder (run times)")
    p.add_argument("--experiment", required=True, help="the experiment's name (the title)")
    p.add_argument("--output", required=True, help="report.html")
    p.set_defaults(func=cmd_report)
    return ap


def main(argv: list[str] | None = None) -> int:
    """Run one step; 0 on success, 2 (one line on stderr) on an error in the user's input."""
    args = parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        import torch  # here, not at the top: `helioflow --help` answers without loading torch

        torch.set_num_threads(args.threads)
        args.func(args)
    except (HelioflowError, json.JSONDecodeError) as exc:
        print(f"helioflow {args.step}: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
