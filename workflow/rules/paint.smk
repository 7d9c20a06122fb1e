# Real calibration data imported from PAINT directories (datasets with `source: paint`). Their
# datasets and heliostat geometries have the same paths as traced ones: the wildcard constraints
# keep these rules to the PAINT names, and trace / surfaces to the others.


rule import_paint:
    """Real focal-spot images, sun positions and targets of a PAINT heliostat, as a dataset."""
    input:
        unpack(lambda wc: import_paint_inputs(config, wc.dataset)),
    output:
        dataset=f"{RESULTS}/datasets/{{dataset}}.h5",
    wildcard_constraints:
        dataset=unbatched(paint_datasets(config), BATCHED_DATASETS),
    params:
        spec=lambda wc: json.dumps(import_paint_params(config, wc.dataset)),
    log:
        f"{RESULTS}/logs/import_paint/{{dataset}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/import_paint/{{dataset}}.tsv"
    threads: 1
    shell:
        "helioflow import-paint --spec {params.spec:q} --output {output.dataset:q} > {log:q} 2>&1"


rule paint_heliostat:
    """The ideal geometry of a PAINT heliostat (Juelich mount, canted facets, no errors)."""
    input:
        unpack(lambda wc: paint_heliostat_inputs(config, wc.heliostat)),
    output:
        geometry=f"{RESULTS}/surfaces/{{heliostat}}.h5",
    wildcard_constraints:
        heliostat=unbatched(paint_heliostats(config), BATCHED_HELIOSTATS),
    params:
        spec=lambda wc: json.dumps(paint_heliostat_params(config, wc.heliostat)),
    log:
        f"{RESULTS}/logs/paint_heliostat/{{heliostat}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/paint_heliostat/{{heliostat}}.tsv"
    threads: 1
    shell:
        "helioflow import-paint --spec {params.spec:q} --heliostat-output {output.geometry:q} > {log:q} 2>&1"


rule paint_centroids:
    """Centroid offset (mrad) of each measured spot from the ideal heliostat's traced spot."""
    input:
        dataset=f"{RESULTS}/datasets/{{dataset}}.h5",
        heliostat=lambda wc: f"{RESULTS}/surfaces/{dataset_heliostat(config, wc.dataset)}.h5",
    output:
        centroids=f"{RESULTS}/paint/{{dataset}}_centroids.json",
    wildcard_constraints:
        dataset=name_pattern(paint_datasets(config)),
    params:
        torch_threads=TORCH_THREADS,
    log:
        f"{RESULTS}/logs/paint_centroids/{{dataset}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/paint_centroids/{{dataset}}.tsv"
    threads: TORCH_THREADS
    shell:
        "helioflow --threads {params.torch_threads:q} paint-centroids --dataset {input.dataset:q}"
        " --heliostat {input.heliostat:q} --output {output.centroids:q} > {log:q} 2>&1"


rule leave_one_out:
    """Held-out scores and pictures of every network on each image of a leave-one-out PAINT dataset."""
    input:
        unpack(lambda wc: leave_one_out_inputs(config, wc.dataset)),
    output:
        csv=f"{RESULTS}/leave_one_out/{{dataset}}.csv",
        figure=f"{RESULTS}/figures/leave_one_out/{{dataset}}.png",
    wildcard_constraints:
        dataset=name_pattern(list(leave_one_out_groups(config))),
    params:
        torch_threads=TORCH_THREADS,
        inputs=lambda wc: json.dumps(leave_one_out_inputs(config, wc.dataset)),
    log:
        f"{RESULTS}/logs/leave_one_out/{{dataset}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/leave_one_out/{{dataset}}.tsv"
    threads: TORCH_THREADS
    shell:
        "helioflow --threads {params.torch_threads:q} leave-one-out --inputs {params.inputs:q} --csv {output.csv:q}"
        " --figure {output.figure:q} > {log:q} 2>&1"


rule plant_table:
    """One row per heliostat of the plant entries (datasets with `heliostats`): held-out errors, the
    diagnosis' named effects, the pointing error of the fitted kinematics with its sigma, canting,
    surface and flags (helioflow.scoring.plant), and the plant's plan coloured by pointing error
    (helioflow.scoring.plant_figure)."""
    input:
        plant_table_inputs(config),
        spec=spec_path(config, "plant_table"),
    output:
        csv=f"{RESULTS}/plant/heliostats.csv",
        plan=f"{RESULTS}/plant/plan.png",
    params:
        torch_threads=TORCH_THREADS,
    log:
        f"{RESULTS}/logs/plant_table/plant_table.log",
    benchmark:
        f"{RESULTS}/benchmarks/plant_table/plant_table.tsv"
    threads: TORCH_THREADS
    shell:
        "helioflow --threads {params.torch_threads:q} plant-table --spec @{input.spec:q} --csv {output.csv:q}"
        " --plan {output.plan:q} > {log:q} 2>&1"


rule plant_shared:
    """What each plant's heliostats share (the sun, the camera), fitted once across them; every
    heliostat's physics model and diagnosis take these values (helioflow.diagnosis.shared)."""
    input:
        plant_shared_inputs(config),
        spec=spec_path(config, "plant_shared"),
    output:
        f"{RESULTS}/plant/shared.json",
    params:
        torch_threads=TORCH_THREADS,
    log:
        f"{RESULTS}/logs/plant_shared/plant_shared.log",
    benchmark:
        f"{RESULTS}/benchmarks/plant_shared/plant_shared.tsv"
    threads: TORCH_THREADS
    shell:
        "helioflow --threads {params.torch_threads:q} plant-shared --spec @{input.spec:q} --output {output:q}"
        " > {log:q} 2>&1"


rule plant_flux:
    """A plant entry's flux maps on its receiver: every heliostat of its PAINT directory, the calibrated
    ones as their fits have them, the rest ideal (helioflow.field.plant)."""
    input:
        lambda wc: plant_flux_inputs(config, wc.plant),
        spec=spec_path(config, "plant_flux"),
    output:
        flux=f"{RESULTS}/plant/flux/{{plant}}.h5",
        figure=f"{RESULTS}/plant/flux/{{plant}}.png",
        metrics=f"{RESULTS}/plant/flux/{{plant}}.json",
    params:
        torch_threads=TORCH_THREADS,
    log:
        f"{RESULTS}/logs/plant_flux/{{plant}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/plant_flux/{{plant}}.tsv"
    wildcard_constraints:
        plant=name_pattern(list(plant_groups(config))),
    threads: TORCH_THREADS
    shell:
        "helioflow --threads {params.torch_threads:q} plant-flux --spec @{input.spec:q} --plant {wildcards.plant:q}"
        " --flux {output.flux:q} --figure {output.figure:q} --metrics {output.metrics:q} > {log:q} 2>&1"


rule plant_aim:
    """A plant entry's aim points under its receiver's flux limit, chosen on the design and on the
    calibrated heliostats, each judged on the calibrated plant (helioflow.field.plant_aim)."""
    input:
        lambda wc: plant_flux_inputs(config, wc.plant),
        spec=spec_path(config, "plant_flux"),
    output:
        json=f"{RESULTS}/plant/aim/{{plant}}.json",
        figure=f"{RESULTS}/plant/aim/{{plant}}.png",
    params:
        torch_threads=TORCH_THREADS,
    log:
        f"{RESULTS}/logs/plant_aim/{{plant}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/plant_aim/{{plant}}.tsv"
    wildcard_constraints:
        plant=name_pattern(list(plant_groups(config))),
    threads: TORCH_THREADS
    shell:
        "helioflow --threads {params.torch_threads:q} plant-aim --spec @{input.spec:q} --plant {wildcards.plant:q}"
        " --output {output.json:q} --figure {output.figure:q} > {log:q} 2>&1"
