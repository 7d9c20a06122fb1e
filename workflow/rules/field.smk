# The field (config `field`): the measured heliostats and their calibration datasets and models are
# generated config entries (helioflow.workflow.expand_field, applied in common.smk), built by the
# surfaces, trace and train rules; compose_field composes the receiver flux maps.
from helioflow.workflow import compose_field_inputs, compose_field_params, write_field_spec


localrules:
    field_spec,


rule field_spec:
    """compose_field's parameters and input lists as a JSON file: they grow with the field (a
    plant's names, positions and seeds), past what one command-line argument may hold."""
    output:
        f"{RESULTS}/field/spec.json",
    params:
        spec=lambda wc: {**compose_field_params(config), **compose_field_inputs(config)},
    log:
        f"{RESULTS}/logs/field_spec/field_spec.log",
    run:
        write_field_spec(params.spec, output[0], log[0])


rule compose_field:
    """Truth, ideal and hybrid flux maps of the field on the receiver for each sun design point."""
    input:
        **compose_field_inputs(config),
        spec=f"{RESULTS}/field/spec.json",
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
