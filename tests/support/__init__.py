"""What the tests import besides helioflow, none of it a test: the independent Monte Carlo that writes
PAINT folders (paint_world), the plant's score against that generator's truth (plant_truth), the
pipeline tests' snakemake runner (pipeline), small fit problems (fit_scenes) and images whose noise is
known (noise_images). tests/ is on sys.path (pyproject.toml's pytest `pythonpath`), so a test imports
`from support.paint_world import World`; scripts/experiments/ put tests/ on sys.path themselves."""
