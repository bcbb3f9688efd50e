"""The names of what a run directory holds, for the modules that write it
(:mod:`gcnt.run.directory`) and read it back (:mod:`gcnt.run.data`)."""

RECIPE_FILE = "recipe.yaml"
METRICS_FILE = "metrics.jsonl"
CHECKPOINT = "checkpoints/last.pt"
