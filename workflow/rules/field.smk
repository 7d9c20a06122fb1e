# The field (config `field`): its heliostats and the measured ones' calibration datasets and models
# are generated config entries (helioflow.workflow.expand_field, applied in common.smk), built by the
# surfaces, trace and train rules; this rule composes the receiver flux maps.
from helioflow.workflow import compose_field_inputs, compose_field_params


rule compose_field:
    """Truth, ideal and hybrid flux maps of the field on the receiver for each sun design point."""
    input:
        **compose_field_inputs(config),
    output:
        flux=f"{RESULTS}/field/flux.h5",
        figure=f"{RESULTS}/field/flux.png",
        metrics=f"{RESULTS}/field/metrics.json",
    params:
        torch_threads=TORCH_THREADS,
        spec=lambda wc: json.dumps(compose_field_params(config)),
    log:
        f"{RESULTS}/logs/compose_field/compose_field.log",
    benchmark:
        f"{RESULTS}/benchmarks/compose_field/compose_field.tsv"
    threads: TORCH_THREADS
    shell:
        "helioflow --threads {params.torch_threads:q} compose-field --spec {params.spec:q} --models {input.models:q}"
        " --datasets {input.datasets:q} --flux {output.flux:q} --figure {output.figure:q}"
        " --metrics {output.metrics:q} > {log:q} 2>&1"
