rule trace:
    """A synthetic calibration dataset: focal-spot images under the world physics, with splits."""
    input:
        heliostat=lambda wc: f"{RESULTS}/surfaces/{dataset_heliostat(config, wc.dataset)}.h5",
    output:
        dataset=f"{RESULTS}/datasets/{{dataset}}.h5",
    params:
        spec=lambda wc: json.dumps(trace_params(config, wc.dataset)),
    log:
        f"{RESULTS}/logs/trace/{{dataset}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/trace/{{dataset}}.tsv"
    threads: 2
    shell:
        "helioflow --threads {threads} trace --spec {params.spec:q} --heliostat {input.heliostat}"
        " --output {output.dataset} > {log} 2>&1"


rule plot_dataset:
    """Sample images of a dataset over its sun positions."""
    input:
        dataset=f"{RESULTS}/datasets/{{dataset}}.h5",
    output:
        figure=report(
            f"{RESULTS}/figures/datasets/{{dataset}}.png",
            caption="../report/dataset_samples.rst",
            category="Datasets",
        ),
    params:
        samples=12,
    log:
        f"{RESULTS}/logs/plot_dataset/{{dataset}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/plot_dataset/{{dataset}}.tsv"
    threads: 1
    shell:
        "helioflow plot-dataset --dataset {input.dataset} --samples {params.samples} --output {output.figure} > {log} 2>&1"
