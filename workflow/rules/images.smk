# One's own calibration images, a folder of PNGs and a CSV (datasets with `source: images`). Their
# datasets and heliostat geometries have the same paths as traced ones; an images dataset's heliostat
# is named like the dataset (surfaces/<dataset>.h5; a leave-one-out fold's like its dataset). The
# wildcard constraints keep these rules to those names, and trace / surfaces / PAINT to the others.


rule import_images:
    """Calibration images, their sun positions and target, from a folder and a CSV, as a dataset."""
    input:
        unpack(lambda wc: import_images_inputs(config, wc.dataset)),
    output:
        dataset=f"{RESULTS}/datasets/{{dataset}}.h5",
    wildcard_constraints:
        dataset=unbatched(images_datasets(config), BATCHED_DATASETS),
    params:
        spec=lambda wc: json.dumps(import_images_params(config, wc.dataset)),
    log:
        f"{RESULTS}/logs/import_images/{{dataset}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/import_images/{{dataset}}.tsv"
    threads: 1
    shell:
        "helioflow import-images --spec {params.spec:q} --output {output.dataset:q} > {log:q} 2>&1"


rule images_heliostat:
    """The ideal geometry of an images dataset's heliostat (inline in config, or a heliostat-properties.json)."""
    input:
        unpack(lambda wc: images_heliostat_inputs(config, wc.heliostat)),
    output:
        geometry=f"{RESULTS}/surfaces/{{heliostat}}.h5",
    wildcard_constraints:
        heliostat=unbatched(images_heliostats(config), BATCHED_HELIOSTATS),
    params:
        spec=lambda wc: json.dumps(images_heliostat_params(config, wc.heliostat)),
    log:
        f"{RESULTS}/logs/images_heliostat/{{heliostat}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/images_heliostat/{{heliostat}}.tsv"
    threads: 1
    shell:
        "helioflow import-images --spec {params.spec:q} --heliostat-output {output.geometry:q} > {log:q} 2>&1"
