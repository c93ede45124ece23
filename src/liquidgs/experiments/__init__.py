"""Experiments: grids of runs (specs), their execution (local or Ray) and their reports.

Sits on top of train/ and eval/; nothing below imports it.
"""

from liquidgs.experiments.plan import (
    Experiment,
    RunEntry,
    expand,
    generate_scenes,
    read_manifest,
    write_manifest,
)
from liquidgs.experiments.spec import BUILTIN_SPECS, ExperimentSpec, Grid, load_spec, spec_from_dict

__all__ = [
    "BUILTIN_SPECS",
    "Experiment",
    "ExperimentSpec",
    "Grid",
    "RunEntry",
    "expand",
    "generate_scenes",
    "load_spec",
    "read_manifest",
    "spec_from_dict",
    "write_manifest",
]
