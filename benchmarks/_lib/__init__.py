"""Helpers shared by the benchmark scripts (not part of the installed package): ``machine`` (the CPU and the
commit a result was made with) and ``coarse`` (a coarse model trained and scored on a dev scene). The scripts
import them as ``_lib.X`` with benchmarks/ on ``sys.path`` (a script's own folder is, when it runs)."""
