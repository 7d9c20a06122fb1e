rule surfaces:
    """A heliostat's true geometry: ideal facets plus its seeded deformation and misalignment."""
    output:
        geometry=f"{RESULTS}/surfaces/{{heliostat}}.h5",
    wildcard_constraints:
        heliostat=name_pattern(list(config["heliostats"])),
    params:
        torch_threads=SHORT_JOB_THREADS,
        spec=lambda wc: json.dumps(surfaces_params(config, wc.heliostat)),
    log:
        f"{RESULTS}/logs/surfaces/{{heliostat}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/surfaces/{{heliostat}}.tsv"
    threads: SHORT_JOB_THREADS
    shell:
        "helioflow --threads {params.torch_threads:q} surfaces --spec {params.spec:q} --output {output.geometry:q} > {log:q} 2>&1"
