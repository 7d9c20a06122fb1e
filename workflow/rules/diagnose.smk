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
        spec=lambda wc: json.dumps(diagnose_params(config, wc.dataset)),
        ledger=lambda wc: f"{RESULTS}/ledger/{wc.dataset}.json",
    log:
        f"{RESULTS}/logs/diagnose/{{dataset}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/diagnose/{{dataset}}.tsv"
    threads: 2
    shell:
        "helioflow --threads {threads} diagnose --spec {params.spec:q} --dataset {input.dataset}"
        " --heliostat {input.heliostat} --output {output.diagnosis} --ledger {params.ledger}"
        " --signatures {output.signatures} --ranking {output.ranking} --residuals {output.residuals}"
        " --ledger-figure {output.ledger} > {log} 2>&1"
