# Validate the config at parse time and bind the package's pure helpers.
import json
import os
import sys

from helioflow.batch import batched_datasets, batched_heliostats, unbatched
from helioflow.config import follow_variant, read_yaml, validate_config
from helioflow.errors import HelioflowError
from helioflow.workflow import (
    NAME,
    all_targets,
    check_readable,
    check_results_dir,
    existing_upstream_files,
    expand_config,
    dataset_heliostat,
    diagnose_params,
    heliostat_path,
    efficiency_metrics,
    evaluate_params,
    import_paint_inputs,
    import_images_inputs,
    import_images_params,
    images_datasets,
    images_heliostat_inputs,
    images_heliostat_params,
    images_heliostats,
    leave_one_out_groups,
    leave_one_out_inputs,
    import_paint_params,
    metrics_paths,
    plan_params,
    name_pattern,
    paint_datasets,
    paint_heliostat_inputs,
    paint_heliostat_params,
    paint_heliostats,
    plant_flux_inputs,
    plant_groups,
    plant_shared_inputs,
    plant_table_inputs,
    shared_inputs,
    results_dir,
    spec_path,
    surfaces_params,
    trace_params,
    traced_datasets,
    train_inputs,
    train_params,
    train_threads,
)

try:
    for configfile_path in workflow.configfiles:  # snakemake's own reading keeps the last of a key given twice
        shown = os.path.relpath(configfile_path)  # as the user named it, where it lies below the working folder
        read_yaml(configfile_path if shown.startswith("..") else shown)
    # config.yaml's sections that name datasets or networks a variant drops follow the variant
    for note in follow_variant(config, workflow.config_settings.overwrite_config):
        print(f"helioflow: {note}", file=sys.stderr)
    # the field's heliostats and calibration datasets, and the leave-one-out folds of PAINT
    # datasets, become config entries of their own
    config = expand_config(validate_config(config, workflow.source_path("../schemas/config.schema.yaml")))
    check_results_dir(config)
    # a corrupt upstream file is reported before snakemake reruns (and first deletes) what was made from it
    check_readable(existing_upstream_files(config))
except HelioflowError as exc:
    sys.exit(f"helioflow: {exc}")

RESULTS = results_dir(config)
# torch CPU threads per job, fixed by config, not by `-j`, so that the same config gives the same
# results however many jobs run at once: torch_threads for the jobs that compute (trace, the fits,
# the networks' training, diagnose, compose_field), one for the short ones (surfaces, plots, scoring,
# the nearest baseline), which -j2 then runs two at a time
TORCH_THREADS = config["torch_threads"]
SHORT_JOB_THREADS = 1


# a plant's heliostats batched by plant.group_size (batches.smk) are left by the per-heliostat rules
BATCHED_DATASETS = set(batched_datasets(config))
BATCHED_HELIOSTATS = set(batched_heliostats(config))
# the datasets rules train, evaluate and diagnose make: every one, or every one not batched
PER_HELIOSTAT_DATASET = unbatched(config["datasets"], BATCHED_DATASETS) if BATCHED_DATASETS else NAME


wildcard_constraints:
    dataset=NAME,
    heliostat=NAME,
    model=r"[a-z]+(-n[0-9]+)?",
