rule trace:
    """A synthetic calibration dataset: focal-spot images under the world physics, with splits."""
    input:
        heliostat=lambda wc: f"{RESULTS}/surfaces/{dataset_heliostat(config, wc.dataset)}.h5",
    output:
        dataset=f"{RESULTS}/datasets/{{dataset}}.h5",
    wildcard_constraints:
        dataset=name_pattern(traced_datasets(config)),
    params:
        torch_threads=TORCH_THREADS,
        spec=lambda wc: json.dumps(trace_params(config, wc.dataset)),
    log:
        f"{RESULTS}/logs/trace/{{dataset}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/trace/{{dataset}}.tsv"
    threads: TORCH_THREADS
    shell:
        "helioflow --threads {params.torch_threads:q} trace --spec {params.spec:q} --heliostat {input.heliostat:q}"
        " --output {output.dataset:q} > {log:q} 2>&1"


rule plot_dataset:
    """Sample images of a dataset over its sun positions."""
    input:
        dataset=f"{RESULTS}/datasets/{{dataset}}.h5",
    output:
        figure=f"{RESULTS}/figures/datasets/{{dataset}}.png",
    params:
        samples=12,
    log:
        f"{RESULTS}/logs/plot_dataset/{{dataset}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/plot_dataset/{{dataset}}.tsv"
    threads: 1
    shell:
        "helioflow plot-dataset --dataset {input.dataset:q} --samples {params.samples:q} --output {output.figure:q} > {log:q} 2>&1"
