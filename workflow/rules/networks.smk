rule train:
    """One network (or a data-efficiency run '<network>-n<images>') trained on a dataset's train split."""
    input:
        unpack(lambda wc: train_inputs(config, wc.dataset, wc.model)),
    output:
        model=f"{RESULTS}/models/{{dataset}}/{{model}}.pt",
        curve=f"{RESULTS}/models/{{dataset}}/{{model}}_curve.csv",
        curve_figure=f"{RESULTS}/models/{{dataset}}/{{model}}_curve.png",
    params:
        spec=lambda wc: json.dumps(train_params(config, wc.dataset, wc.model)),
    log:
        f"{RESULTS}/logs/train/{{dataset}}/{{model}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/train/{{dataset}}/{{model}}.tsv"
    threads: 2
    shell:
        "helioflow --threads {threads} train --spec {params.spec:q} --dataset {input.dataset}"
        " --output {output.model} --curve {output.curve} --curve-figure {output.curve_figure} > {log} 2>&1"


rule evaluate:
    """Scores of a model on every split, per-image CSV, sample grid and PSNR against sun position."""
    input:
        model=f"{RESULTS}/models/{{dataset}}/{{model}}.pt",
        dataset=f"{RESULTS}/datasets/{{dataset}}.h5",
    output:
        metrics=f"{RESULTS}/metrics/{{dataset}}/{{model}}.json",
        per_image=f"{RESULTS}/metrics/{{dataset}}/{{model}}.csv",
        grid=report(
            f"{RESULTS}/figures/{{dataset}}/{{model}}_samples.png",
            caption="../report/samples.rst",
            category="Networks",
        ),
        psnr=report(
            f"{RESULTS}/figures/{{dataset}}/{{model}}_psnr.png",
            caption="../report/psnr.rst",
            category="Networks",
        ),
    params:
        spec=lambda wc: json.dumps(evaluate_params(config)),
    log:
        f"{RESULTS}/logs/evaluate/{{dataset}}/{{model}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/evaluate/{{dataset}}/{{model}}.tsv"
    threads: 1
    shell:
        "helioflow --threads {threads} evaluate --spec {params.spec:q} --model {input.model}"
        " --dataset {input.dataset} --metrics {output.metrics} --per-image {output.per_image}"
        " --grid {output.grid} --psnr {output.psnr} > {log} 2>&1"


rule recovery:
    """What drt recovered of a synthetic dataset's true heliostat (tracking, pointing, surface, canting, slope error)."""
    input:
        model=f"{RESULTS}/models/{{dataset}}/drt.pt",
        heliostat=lambda wc: heliostat_path(config, wc.dataset),
        dataset=f"{RESULTS}/datasets/{{dataset}}.h5",
    output:
        f"{RESULTS}/recovery/{{dataset}}.json",
    log:
        f"{RESULTS}/logs/recovery/{{dataset}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/recovery/{{dataset}}.tsv"
    threads: 1
    shell:
        "helioflow recovery --model {input.model} --heliostat {input.heliostat} --dataset {input.dataset}"
        " --output {output} > {log} 2>&1"


rule table:
    """Table 1: network x dataset x split (PSNR, SSIM) with controllability."""
    input:
        metrics=metrics_paths(config),
    output:
        csv=f"{RESULTS}/tables/table1.csv",
        markdown=report(f"{RESULTS}/tables/table1.md", caption="../report/table.rst", category="Networks"),
    params:
        networks=list(config.get("networks") or {}),
    log:
        f"{RESULTS}/logs/table/table1.log",
    benchmark:
        f"{RESULTS}/benchmarks/table/table1.tsv"
    threads: 1
    shell:
        "helioflow table --metrics {input.metrics} --csv {output.csv} --markdown {output.markdown} > {log} 2>&1"


rule data_efficiency:
    """Interpolation/extrapolation PSNR against the number of training images."""
    input:
        metrics=efficiency_metrics(config),
    output:
        figure=report(
            f"{RESULTS}/figures/data_efficiency.png",
            caption="../report/data_efficiency.rst",
            category="Networks",
        ),
        csv=f"{RESULTS}/tables/data_efficiency.csv",
    params:
        train_images=(config.get("data_efficiency") or {}).get("train_images", []),
    log:
        f"{RESULTS}/logs/data_efficiency/data_efficiency.log",
    benchmark:
        f"{RESULTS}/benchmarks/data_efficiency/data_efficiency.tsv"
    threads: 1
    shell:
        "helioflow data-efficiency --metrics {input.metrics} --figure {output.figure} --csv {output.csv} > {log} 2>&1"
