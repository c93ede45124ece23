"""`liquidgs experiment {run,report,list}`: grids of runs and the paper's tables from them.

    liquidgs experiment run SPEC --data-root DIR [--out DIR] [--executor local|ray]
                            [--ray-address ADDR] [--parallel N] [--dry-run]
    liquidgs experiment report SPEC_OR_DIR [--out DIR] [--eval final|best_of] [--references]
    liquidgs experiment list

SPEC is a built-in spec name (`liquidgs experiment list`) or a YAML file. Runs go to
DIR/<dataset>/<scene>/<field>/<config hash>/ (default DIR: outputs/experiments/<spec name>);
finished runs are skipped, interrupted ones resumed, and a failed run does not stop the others.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import tyro
from rich.console import Console

from liquidgs.commands.progress import progress_for
from liquidgs.errors import ConfigError
from liquidgs.experiments import BUILTIN_SPECS, expand, generate_scenes, load_spec, read_manifest, write_manifest
from liquidgs.experiments.estimate import estimate
from liquidgs.experiments.plan import MANIFEST, RunEntry, check_same_experiment
from liquidgs.experiments.runner import RunOutcome, finished_elsewhere, run_experiment
from liquidgs.settings import parse_flags

EXPERIMENTS_ROOT = Path("outputs") / "experiments"


@dataclass
class RunArgs:
    spec: tyro.conf.Positional[str]
    """Built-in spec name or YAML file."""
    data_root: Path
    """Folder holding the scenes (as <scene>/ or <dataset>/<scene>/)."""
    out: Path | None = None
    """Experiment folder (default outputs/experiments/<spec name>)."""
    executor: Literal["local", "ray"] = "local"
    """local: runs in processes on this machine (--parallel at a time); ray: on a Ray cluster (--ray-address)."""
    ray_address: str | None = None
    """An existing Ray cluster (e.g. 'auto' or 'ray://head:10001'); default: a local Ray instance."""
    parallel: int | None = None
    """Runs at a time (default: one per GPU; on a CPU one single-threaded run per core, up to 8)."""
    dry_run: bool = False
    """Print the runs and where they would go; train nothing."""


@dataclass
class ReportArgs:
    spec_or_dir: tyro.conf.Positional[str]
    """An experiment folder, or a spec name / YAML file (its default folder)."""
    out: Path | None = None
    """Report folder (default <experiment>/report)."""
    eval: Literal["final", "best_of"] = "final"
    """Which evaluation every number is: the last iteration, or the best test PSNR during training."""
    references: bool = False
    """Add the paper's printed numbers and the published D-3DGS numbers, with the difference per cell."""


def experiment_dir(spec_name: str, out: Path | None) -> Path:
    return out if out is not None else EXPERIMENTS_ROOT / spec_name


def run(args: RunArgs, console: Console) -> int:
    if args.parallel is not None and args.parallel < 1:
        raise ConfigError(f"--parallel must be >= 1, got {args.parallel}")
    spec = load_spec(args.spec)
    experiment = expand(spec, args.data_root, experiment_dir(spec.name, args.out))
    unchanged = check_same_experiment(experiment)
    done = [r for r in experiment.runs if r.is_done(experiment.directory)]
    if args.dry_run:
        shared, twins, to_train = 0, 0, []
        first_of: dict[str, RunEntry] = {}
        for entry in experiment.runs:
            twin = first_of.setdefault(entry.run_dir, entry)
            donor = None if entry in done else finished_elsewhere(entry, experiment.directory)
            if twin is not entry and entry not in done:
                state, where, twins = "twin", f"the same run as {twin.name} (trained once)", twins + 1
            else:
                state = "done" if entry in done else "shared" if donor is not None else "to run"
                where = donor or entry.folder(experiment.directory)
                shared += donor is not None
                to_train += [entry] if state == "to run" else []
            print(f"{entry.name:<44} {state:<7} {where}")
        also = f", {shared} finished in another experiment, to be shared" if shared else ""
        also += f", {twins} the same run as another row (SDE at lambda 0 = CfC), trained once" if twins else ""
        print(f"{len(experiment.runs)} runs ({len(done)} done{also}) in {experiment.directory}; "
              "nothing was run (--dry-run)")  # fmt: skip
        print(estimate(to_train).line(len(to_train)))
        return 0
    if not unchanged and (experiment.directory / MANIFEST).is_file():
        console.print(
            f"note: spec '{spec.name}' changed since it last ran in {experiment.directory}; {MANIFEST} now lists "
            "its new grids (runs no longer in them stay in their folders, out of its report)"
        )
    write_manifest(experiment)
    for folder in generate_scenes(experiment):
        console.print(f"generated the built-in scene {folder}")
    console.print(
        f"experiment {spec.name}: {len(experiment.runs)} runs, {len(done)} already done, executor {args.executor} "
        f"-> {experiment.directory}"
    )
    outcomes: list[RunOutcome] = []

    def line(task: dict) -> str:
        return f"{task['description']}: {task['completed']}/{task['total']} runs  {task['last']}".rstrip()

    counts, fields = "{task.completed}/{task.total} runs", "{task.fields[last]}"
    with progress_for(console, counts, fields, line, every_update=True) as progress:
        task = progress.add_task(spec.name, total=len(experiment.runs), last="")

        def record(outcome: RunOutcome) -> None:
            outcomes.append(outcome)
            progress.update(task, advance=1, last=f"{outcome.status}: {outcome.name}")

        run_experiment(experiment, args.executor, args.parallel, args.ray_address, on_outcome=record)
    counts = {status: sum(o.status == status for o in outcomes) for status in ("done", "skipped", "failed")}
    console.print(f"done {counts['done']}, skipped {counts['skipped']} (finished before), failed {counts['failed']}")
    for outcome in outcomes:
        if outcome.status == "skipped" and outcome.message:
            console.print(f"  {outcome.name}: {outcome.message}")
    for outcome in outcomes:
        if outcome.status == "failed":
            console.print(f"  [red]failed[/] {outcome.name}: {outcome.message}\n         log: {outcome.log}")
    if counts["failed"]:
        return 1
    console.print(f"report: liquidgs experiment report {experiment.directory}")
    return 0


def report(args: ReportArgs, console: Console) -> int:
    from liquidgs.experiments.report import write_report

    target = Path(args.spec_or_dir)
    if not (target / MANIFEST).is_file():
        if target.is_dir():
            read_manifest(target)  # raises: a folder that is not an experiment
        target = experiment_dir(load_spec(args.spec_or_dir).name, None)
    experiment = read_manifest(target)
    path = write_report(experiment.directory, args.out, evaluation=args.eval, references=args.references)
    console.print(f"report: {path}")
    return 0


def list_specs() -> int:
    for name, spec in BUILTIN_SPECS.items():
        runs = sum(g.run_count() for g in spec.grids)
        print(f"{name:<13} {runs:>4} runs  {spec.description}")
    return 0


def main(argv: list[str]) -> int:
    usage = "usage: liquidgs experiment {run,report,list} [ARGS...]  (see --help of each)"
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__ if argv else usage, file=sys.stderr if not argv else sys.stdout)
        return 0 if argv else 2
    action, rest = argv[0], argv[1:]
    console = Console(stderr=True, soft_wrap=True)  # failure lines hold paths: never wrap them
    if action == "run":
        return run(parse_flags(RunArgs, rest, prog="liquidgs experiment run", description=__doc__), console)
    if action == "report":
        return report(parse_flags(ReportArgs, rest, prog="liquidgs experiment report", description=__doc__), console)
    if action == "list":
        return list_specs()
    raise ConfigError(f"unknown experiment action '{action}' ({', '.join(ACTIONS)})")


# Each action's settings (none for list) and one line on what it does (the command catalog's).
ACTIONS: dict[str, tuple[type | None, str]] = {
    "run": (RunArgs, "Train every run of a spec (skipping finished runs, resuming interrupted ones)"),
    "report": (ReportArgs, "The paper's tables, seed spread, margins and figures from an experiment's runs"),
    "list": (None, "The built-in specs, each with its number of runs"),
}
