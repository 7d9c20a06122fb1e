rule surfaces:
    """A heliostat's true geometry: ideal facets plus its seeded deformation and misalignment."""
    output:
        geometry=f"{RESULTS}/surfaces/{{heliostat}}.h5",
    params:
        spec=lambda wc: json.dumps(surfaces_params(config, wc.heliostat)),
    log:
        f"{RESULTS}/logs/surfaces/{{heliostat}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/surfaces/{{heliostat}}.tsv"
    threads: 1
    shell:
        "helioflow --threads {threads} surfaces --spec {params.spec:q} --output {output.geometry} > {log} 2>&1"
