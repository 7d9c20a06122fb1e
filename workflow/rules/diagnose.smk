rule diagnose:
    """Where the model physics fails against a dataset's measurements, and which effect is missing."""
    input:
        dataset=f"{RESULTS}/datasets/{{dataset}}.h5",
        heliostat=lambda wc: heliostat_path(config, wc.dataset),
    output:
        diagnosis=f"{RESULTS}/diagnosis/{{dataset}}.json",
        signatures=report(
            f"{RESULTS}/figures/diagnosis/{{dataset}}_signatures.png",
            caption="../report/diagnosis_signatures.rst",
            category="Diagnosis",
        ),
        ranking=report(
            f"{RESULTS}/figures/diagnosis/{{dataset}}_ranking.png",
            caption="../report/diagnosis_ranking.rst",
            category="Diagnosis",
        ),
        residuals=report(
            f"{RESULTS}/figures/diagnosis/{{dataset}}_residuals.png",
            caption="../report/diagnosis_residuals.rst",
            category="Diagnosis",
        ),
        ledger=report(
            f"{RESULTS}/figures/diagnosis/{{dataset}}_ledger.png",
            caption="../report/diagnosis_ledger.rst",
            category="Diagnosis",
        ),
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
        " --ledger-figure {output.ledger:q} > {log:q} 2>&1"
