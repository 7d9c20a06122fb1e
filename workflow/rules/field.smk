# The field (config `field`): the measured heliostats and their calibration datasets and models are
# generated config entries (helioflow.workflow.expand_field, applied in common.smk), built by the
# surfaces, trace and train rules; compose_field composes the receiver flux maps. Its parameters
# (every field heliostat's name, position and seed) come in specs/compose_field.json (rule spec).
from helioflow.workflow import compose_field_inputs, spec_path


rule compose_field:
    """Truth, ideal and hybrid flux maps of the field on the receiver for each sun design point."""
    input:
        **compose_field_inputs(config),
        spec=spec_path(config, "compose_field"),
    output:
        flux=f"{RESULTS}/field/flux.h5",
        figure=f"{RESULTS}/field/flux.png",
        metrics=f"{RESULTS}/field/metrics.json",
    params:
        torch_threads=TORCH_THREADS,
    log:
        f"{RESULTS}/logs/compose_field/compose_field.log",
    benchmark:
        f"{RESULTS}/benchmarks/compose_field/compose_field.tsv"
    threads: TORCH_THREADS
    shell:
        "helioflow --threads {params.torch_threads:q} compose-field --spec @{input.spec:q}"
        " --flux {output.flux:q} --figure {output.figure:q} --metrics {output.metrics:q} > {log:q} 2>&1"


rule optimise_aim:
    """Aim points chosen on the ideal, the hybrid and the true field, each judged on the true field
    (config field.optimise_aim)."""
    input:
        **compose_field_inputs(config),
        spec=spec_path(config, "optimise_aim"),
    output:
        figure=f"{RESULTS}/field/aim.png",
        metrics=f"{RESULTS}/field/aim.json",
    params:
        torch_threads=TORCH_THREADS,
    log:
        f"{RESULTS}/logs/optimise_aim/optimise_aim.log",
    benchmark:
        f"{RESULTS}/benchmarks/optimise_aim/optimise_aim.tsv"
    threads: TORCH_THREADS
    shell:
        "helioflow --threads {params.torch_threads:q} optimise-aim --spec @{input.spec:q}"
        " --figure {output.figure:q} --metrics {output.metrics:q} > {log:q} 2>&1"
