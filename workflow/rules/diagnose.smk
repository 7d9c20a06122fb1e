rule diagnose:
    """Where the model physics fails against a dataset's measurements, and which effect is missing."""
    input:
        dataset=f"{RESULTS}/datasets/{{dataset}}.h5",
        heliostat=lambda wc: heliostat_path(config, wc.dataset),
        shared=lambda wc: shared_inputs(config, wc.dataset),  # a plant's heliostat: the plant fit's shared effects
    output:
        diagnosis=f"{RESULTS}/diagnosis/{{dataset}}.json",
        signatures=f"{RESULTS}/figures/diagnosis/{{dataset}}_signatures.png",
        ranking=f"{RESULTS}/figures/diagnosis/{{dataset}}_ranking.png",
        residuals=f"{RESULTS}/figures/diagnosis/{{dataset}}_residuals.png",
        location=f"{RESULTS}/figures/diagnosis/{{dataset}}_location.png",
        ledger=f"{RESULTS}/figures/diagnosis/{{dataset}}_ledger.png",
    wildcard_constraints:
        dataset=PER_HELIOSTAT_DATASET,
    params:
        torch_threads=TORCH_THREADS,
        spec=lambda wc: json.dumps(diagnose_params(config, wc.dataset)),
        ledger=lambda wc: f"{RESULTS}/ledger/{wc.dataset}.json",
    log:
        f"{RESULTS}/logs/diagnose/{{dataset}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/diagnose/{{dataset}}.tsv"
    threads: TORCH_THREADS
    shell:
        "helioflow --threads {params.torch_threads:q} diagnose --spec {params.spec:q} --dataset {input.dataset:q}"
        " --heliostat {input.heliostat:q} --output {output.diagnosis:q} --ledger {params.ledger:q}"
        " --signatures {output.signatures:q} --ranking {output.ranking:q} --residuals {output.residuals:q}"
        " --location {output.location:q}"
        " --ledger-figure {output.ledger:q} > {log:q} 2>&1"
