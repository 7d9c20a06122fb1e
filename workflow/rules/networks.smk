rule train:
    """One network (or a data-efficiency run '<network>-n<images>') trained on a dataset's train split."""
    input:
        unpack(lambda wc: train_inputs(config, wc.dataset, wc.model)),
    output:
        model=f"{RESULTS}/models/{{dataset}}/{{model}}.pt",
        curve=f"{RESULTS}/models/{{dataset}}/{{model}}_curve.csv",
        curve_figure=f"{RESULTS}/models/{{dataset}}/{{model}}_curve.png",
    wildcard_constraints:
        dataset=PER_HELIOSTAT_DATASET,
    params:
        torch_threads=lambda wc: train_threads(config, wc.dataset, wc.model),
        spec=lambda wc: json.dumps(train_params(config, wc.dataset, wc.model)),
    log:
        f"{RESULTS}/logs/train/{{dataset}}/{{model}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/train/{{dataset}}/{{model}}.tsv"
    threads: lambda wc: train_threads(config, wc.dataset, wc.model)
    shell:
        "helioflow --threads {params.torch_threads:q} train --spec {params.spec:q} --dataset {input.dataset:q}"
        " --output {output.model:q} --curve {output.curve:q} --curve-figure {output.curve_figure:q} > {log:q} 2>&1"


rule evaluate:
    """Scores of a model on every split, per-image CSV, sample grid and PSNR against sun position."""
    input:
        model=f"{RESULTS}/models/{{dataset}}/{{model}}.pt",
        dataset=f"{RESULTS}/datasets/{{dataset}}.h5",
    output:
        metrics=f"{RESULTS}/metrics/{{dataset}}/{{model}}.json",
        per_image=f"{RESULTS}/metrics/{{dataset}}/{{model}}.csv",
        grid=f"{RESULTS}/figures/{{dataset}}/{{model}}_samples.png",
        psnr=f"{RESULTS}/figures/{{dataset}}/{{model}}_psnr.png",
    wildcard_constraints:
        dataset=PER_HELIOSTAT_DATASET,
    params:
        torch_threads=SHORT_JOB_THREADS,
        spec=lambda wc: json.dumps(evaluate_params(config)),
    log:
        f"{RESULTS}/logs/evaluate/{{dataset}}/{{model}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/evaluate/{{dataset}}/{{model}}.tsv"
    threads: SHORT_JOB_THREADS
    shell:
        "helioflow --threads {params.torch_threads:q} evaluate --spec {params.spec:q} --model {input.model:q}"
        " --dataset {input.dataset:q} --metrics {output.metrics:q} --per-image {output.per_image:q}"
        " --grid {output.grid:q} --psnr {output.psnr:q} > {log:q} 2>&1"


rule recovery:
    """What drt recovered of a synthetic dataset's true heliostat (tracking, pointing, surface, canting, slope error)."""
    input:
        model=f"{RESULTS}/models/{{dataset}}/drt.pt",
        heliostat=lambda wc: heliostat_path(config, wc.dataset),
        dataset=f"{RESULTS}/datasets/{{dataset}}.h5",
    output:
        f"{RESULTS}/recovery/{{dataset}}.json",
    params:
        torch_threads=SHORT_JOB_THREADS,
        device=config["device"],
    log:
        f"{RESULTS}/logs/recovery/{{dataset}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/recovery/{{dataset}}.tsv"
    threads: SHORT_JOB_THREADS
    shell:
        "helioflow --threads {params.torch_threads:q} recovery --model {input.model:q} --heliostat {input.heliostat:q}"
        " --dataset {input.dataset:q} --device {params.device:q} --output {output:q} > {log:q} 2>&1"


rule fitted_heliostat:
    """The heliostat drt found for a real dataset: surface deviation on a grid, slope error, canting, tracking, with sigma."""
    input:
        f"{RESULTS}/models/{{dataset}}/drt.pt",
    output:
        json=f"{RESULTS}/heliostats/{{dataset}}.json",
        figure=f"{RESULTS}/heliostats/{{dataset}}.png",
    params:
        torch_threads=SHORT_JOB_THREADS,
    log:
        f"{RESULTS}/logs/fitted_heliostat/{{dataset}}.log",
    threads: SHORT_JOB_THREADS
    shell:
        "helioflow --threads {params.torch_threads:q} fitted-heliostat --model {input:q} --output {output.json:q}"
        " --figure {output.figure:q} > {log:q} 2>&1"


rule table:
    """Table 1: network x dataset x split (PSNR, SSIM) with controllability."""
    input:
        metrics=metrics_paths(config),
        spec=spec_path(config, "table"),
    output:
        csv=f"{RESULTS}/tables/table1.csv",
        markdown=f"{RESULTS}/tables/table1.md",
    params:
        networks=list(config.get("networks") or {}),
    log:
        f"{RESULTS}/logs/table/table1.log",
    benchmark:
        f"{RESULTS}/benchmarks/table/table1.tsv"
    threads: 1
    shell:
        "helioflow table --metrics @{input.spec:q} --csv {output.csv:q} --markdown {output.markdown:q} > {log:q} 2>&1"


rule data_efficiency:
    """Interpolation/extrapolation PSNR against the number of training images."""
    input:
        metrics=efficiency_metrics(config),
        spec=spec_path(config, "data_efficiency"),
    output:
        figure=f"{RESULTS}/figures/data_efficiency.png",
        csv=f"{RESULTS}/tables/data_efficiency.csv",
    params:
        train_images=(config.get("data_efficiency") or {}).get("train_images", []),
    log:
        f"{RESULTS}/logs/data_efficiency/data_efficiency.log",
    benchmark:
        f"{RESULTS}/benchmarks/data_efficiency/data_efficiency.tsv"
    threads: 1
    shell:
        "helioflow data-efficiency --metrics @{input.spec:q} --figure {output.figure:q} --csv {output.csv:q}"
        " > {log:q} 2>&1"


rule plan_measurements:
    """The next calibration images of a dataset: the sun positions that shrink drt's uncertainty most."""
    input:
        model=f"{RESULTS}/models/{{dataset}}/drt.pt",
        dataset=f"{RESULTS}/datasets/{{dataset}}.h5",
    output:
        f"{RESULTS}/plan/{{dataset}}.json",
    params:
        torch_threads=TORCH_THREADS,
        spec=lambda wc: json.dumps(plan_params(config, wc.dataset)),
    log:
        f"{RESULTS}/logs/plan_measurements/{{dataset}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/plan_measurements/{{dataset}}.tsv"
    threads: TORCH_THREADS
    shell:
        "helioflow --threads {params.torch_threads:q} plan-measurements --spec {params.spec:q} --model {input.model:q}"
        " --dataset {input.dataset:q} --output {output:q} > {log:q} 2>&1"
