"""go_pipeline: the runner (DAG from pipeline.yaml, cache keys, artifact store, locks) and the CLI.

The only package that imports the steps (installed as ``go_pipeline.steps`` from the top-level steps/).
"""

__version__ = "0.1.0"
