# The experiment's report: the target of `rule all`. Its inputs are every final output of the
# config (helioflow.workflow.report_inputs, by section); its run times come from the benchmarks.
from helioflow.workflow import report_inputs, report_path, spec_path


rule report:
    """Self-contained HTML report (figures inline, readable offline) of the whole experiment."""
    input:
        **report_inputs(config),
        spec=spec_path(config, "report"),
    output:
        html=report_path(config),
    params:
        benchmarks=f"{RESULTS}/benchmarks",
        experiment=config["experiment"],
    log:
        f"{RESULTS}/logs/report/report.log",
    benchmark:
        f"{RESULTS}/benchmarks/report/report.tsv"
    threads: 1
    shell:
        "helioflow report --inputs @{input.spec:q} --benchmarks {params.benchmarks:q}"
        " --experiment {params.experiment:q} --output {output.html:q} > {log:q} 2>&1"
