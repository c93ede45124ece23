"""The report of an experiment: per-scene, noise-study, seed-spread and cost tables, and figures.

`write_report(experiment_dir)` reads the manifest and every finished run and writes
report.md, tables.tex and PNG figures (default: experiment_dir/report/).
"""

from liquidgs.experiments.report.write import write_report

__all__ = ["write_report"]
