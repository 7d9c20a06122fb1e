# helioflow: heliostat focal spots from calibration images. See README.md.
from snakemake.utils import min_version

min_version("9.0")


configfile: "config.yaml"


include: "workflow/rules/common.smk"
include: "workflow/rules/surfaces.smk"
include: "workflow/rules/trace.smk"
include: "workflow/rules/paint.smk"
include: "workflow/rules/images.smk"
include: "workflow/rules/networks.smk"
include: "workflow/rules/field.smk"
include: "workflow/rules/diagnose.smk"
include: "workflow/rules/batches.smk"
include: "workflow/rules/report.smk"
include: "workflow/rules/specs.smk"


rule all:
    default_target: True
    input:
        all_targets(config),
