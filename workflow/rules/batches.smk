# A plant's heliostats in groups of config plant.group_size (helioflow/batch.py): one rule per group
# and step (import, train, evaluate, diagnose), named '<step>_batch_<plant>_g<k>', runs the step for
# the group in one process and writes each heliostat's outputs and log where the per-heliostat rules
# do; those rules leave the batched datasets (their wildcard constraints in common.smk). Rerun a
# group's step with `--forcerun <step>_batch_<plant>_g<k>`. A group's job runs on one torch thread,
# so that -j runs groups side by side: on these small fits two jobs of one thread each do 1.5x the
# work of one job of two threads (docs/benchmarks.md).
from helioflow.batch import batch_jobs, rule_name

for (_stage, _batch), _job in batch_jobs(config).items():

    rule:
        name:
            rule_name(_stage, _batch)
        input:
            _job["input"],
        output:
            _job["output"],
        params:
            commands=json.dumps(_job["commands"]),
            torch_threads=SHORT_JOB_THREADS,
        log:
            f"{RESULTS}/logs/batch/{_stage}/{_batch}.log",
            _job["logs"],
        benchmark:
            f"{RESULTS}/benchmarks/batch_{_stage}/{_batch}.tsv"
        threads: SHORT_JOB_THREADS
        shell:
            "helioflow --threads {params.torch_threads:q} batch --commands {params.commands:q} > {log[0]:q} 2>&1"
