"""Executing an experiment: every run as a `liquidgs train` subprocess, locally or as Ray tasks.

results.json is the only "done" marker: a run that has it is skipped, a run with a
checkpoint but no results is resumed, anything else starts afresh. The decision is taken
when the run starts (not when the grid is planned), so a Ray task retried after its worker
died resumes from the checkpoint its first attempt left.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from queue import Queue

from liquidgs.errors import ConfigError
from liquidgs.experiments.plan import Experiment, RunEntry, distinct_runs
from liquidgs.train.config import folder_names, save_yaml
from liquidgs.train.run_folder import CHECKPOINT, RESULTS

LOGS = "logs"
EXECUTORS = ("local", "ray")


@dataclass(frozen=True)
class RunOutcome:
    name: str
    status: str  # "done" (trained now), "skipped" (finished before) or "failed"
    seconds: float
    log: str
    message: str = ""


def log_path(experiment_dir: Path, entry: RunEntry) -> Path:
    return Path(experiment_dir) / LOGS / f"{entry.name}.log"


def config_path(experiment_dir: Path, entry: RunEntry) -> Path:
    return Path(experiment_dir) / LOGS / f"{entry.name}.config.yml"


def train_command(entry: RunEntry, experiment_dir: Path) -> list[str]:
    """`liquidgs train` on the run's resolved configuration (written next to its log), or on the
    run folder's own once it has a checkpoint to resume."""
    folder = entry.folder(experiment_dir)
    command = [sys.executable, "-m", "liquidgs.cli", "train", "--out", str(folder)]
    if (folder / CHECKPOINT).is_file():
        return [*command, "--resume"]
    config = config_path(experiment_dir, entry)
    save_yaml(entry.train_config(), config)
    return [*command, "--config", str(config)]


def _die_with_parent() -> None:
    """Linux: the training process gets SIGKILL when the process that started it dies, so a
    killed Ray worker never leaves an orphan training holding the run folder."""
    with contextlib.suppress(OSError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG


def _last_line(path: Path) -> str:
    try:
        lines = [ln.strip() for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    return lines[-1][:300] if lines else ""


# The trainings this process started and waits for: Ctrl-C reaches each (run_local), also when
# only this process got it (a kill -INT of its PID), so each ends with a checkpoint to resume.
_RUNNING: set[subprocess.Popen] = set()
_RUNNING_LOCK = threading.Lock()


def execute_run(entry: RunEntry, experiment_dir: str, env: dict[str, str] | None = None) -> RunOutcome:
    """Train one run to completion (or find it done); never raises for a failed training."""
    experiment_dir = Path(experiment_dir)
    log = log_path(experiment_dir, entry)
    if entry.is_done(experiment_dir):
        return RunOutcome(entry.name, "skipped", 0.0, str(log))
    log.parent.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    command = train_command(entry, experiment_dir)
    with open(log, "a") as stream:
        stream.write(f"$ {' '.join(command)}\n")
        stream.flush()
        process = subprocess.Popen(
            command,
            stdout=stream,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            env={**os.environ, **(env or {}), "PYTHONUNBUFFERED": "1"},
            preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None,
        )
        with _RUNNING_LOCK:
            _RUNNING.add(process)
        try:
            code = process.wait()
        finally:
            with _RUNNING_LOCK:
                _RUNNING.discard(process)
    seconds = time.perf_counter() - started
    if code == 0 and entry.is_done(experiment_dir):
        return RunOutcome(entry.name, "done", seconds, str(log))
    reason = _last_line(log) or f"exit code {code}"
    return RunOutcome(entry.name, "failed", seconds, str(log), f"exit code {code}: {reason}")


def _gpu_count() -> int:
    try:
        import torch

        return torch.cuda.device_count()
    except Exception:  # noqa: BLE001 - no usable torch/CUDA means no GPUs to share out
        return 0


def default_parallel() -> int:
    """One run per GPU; on a CPU one single-threaded run per core (up to 8): small runs spend
    much of a step in single-threaded work, and two one-thread tiny runs on 2 cores finished in
    the time of one two-thread run (measured, 64 px puppet, MLP, 1,000 iterations: 41 vs 40 s)."""
    gpus = _gpu_count()
    return gpus if gpus else max(1, min(8, os.cpu_count() or 1))


def _slot_environments(parallel: int) -> list[dict[str, str]]:
    """Each slot's GPU. On a CPU a run takes the threads `liquidgs train` takes by hand in the
    same shell (train.run.training_threads), so a spec's run and the same run by hand agree."""
    gpus = _gpu_count()
    if gpus:
        return [{"CUDA_VISIBLE_DEVICES": str(slot % gpus)} for slot in range(parallel)]
    return [{} for _ in range(parallel)]


def run_local(
    runs: list[RunEntry], experiment_dir: Path, parallel: int, on_outcome: Callable[[RunOutcome], None]
) -> list[RunOutcome]:
    """Subprocesses, `parallel` at a time, each slot with its own GPU (or share of the CPU cores)."""
    slots: Queue[dict[str, str]] = Queue()
    for env in _slot_environments(parallel):
        slots.put(env)

    interrupted = threading.Event()
    started: list[str] = []

    def in_slot(entry: RunEntry) -> RunOutcome | None:
        env = slots.get()
        try:
            if interrupted.is_set():  # Ctrl-C: no new run starts
                return None
            started.append(entry.name)
            return execute_run(entry, str(experiment_dir), env)
        finally:
            slots.put(env)

    outcomes: list[RunOutcome] = []
    with ThreadPoolExecutor(max_workers=parallel) as pool:
        try:
            for future in as_completed([pool.submit(in_slot, entry) for entry in runs]):
                outcomes.append(future.result())
                on_outcome(outcomes[-1])
        except KeyboardInterrupt:
            interrupted.set()  # before anything else: a slot freed now starts nothing
            pool.shutdown(wait=False, cancel_futures=True)
            with _RUNNING_LOCK:
                for process in _RUNNING:
                    with contextlib.suppress(OSError):
                        process.send_signal(signal.SIGINT)
            pool.shutdown(wait=True)
            raise KeyboardInterrupt(
                f"{len(runs) - len(started)} of {len(runs)} runs not started; the same command resumes the experiment"
            ) from None
    return outcomes


def import_ray():
    try:
        import ray
    except ImportError:
        raise ConfigError(
            "--executor ray needs Ray, which is not installed: "
            "pip install ray (or, in the clone, pip install -e '.[ray]')"
        ) from None
    return ray


def run_ray(
    runs: Iterable[RunEntry],
    experiment_dir: Path,
    parallel: int,
    on_outcome: Callable[[RunOutcome], None],
    address: str | None = None,
    max_retries: int = 3,
) -> list[RunOutcome]:
    """One Ray task per run (one GPU each where the cluster has GPUs). A task whose worker dies is
    retried by Ray and resumes from the run's checkpoint; each run yields exactly one outcome."""
    ray = import_ray()
    started_here = not ray.is_initialized()
    if started_here:
        if address:
            ray.init(address=address, log_to_driver=False)
        else:
            ray.init(num_cpus=parallel, include_dashboard=False, log_to_driver=False)
    try:
        gpus = ray.cluster_resources().get("GPU", 0)
        task = ray.remote(execute_run).options(num_cpus=1, num_gpus=1 if gpus else 0, max_retries=max_retries)
        pending = {task.remote(entry, str(Path(experiment_dir).resolve())): entry for entry in runs}
        outcomes = []
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            entry = pending.pop(ready[0])
            try:
                outcome = ray.get(ready[0])
            except Exception as err:  # noqa: BLE001 - retries exhausted: report the run, keep going
                first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
                outcome = RunOutcome(
                    entry.name, "failed", 0.0, str(log_path(experiment_dir, entry)), f"Ray task failed: {first}"
                )
            outcomes.append(outcome)
            on_outcome(outcome)
        return outcomes
    finally:
        if started_here:
            ray.shutdown()


def finished_elsewhere(entry: RunEntry, experiment_dir: Path) -> Path | None:
    """The same run finished in a sibling experiment folder, when this experiment has no folder for it.

    Runs are folders named by their configuration's hash, so the same path under another experiment
    of the same parent folder (outputs/experiments/noise-study beside .../paper-dnerf) holds the same
    run. A folder of this experiment's own (an unfinished run) is never replaced, so then None.
    """
    directory = Path(experiment_dir)
    folder = entry.folder(directory)
    if folder.exists() or folder.is_symlink() or not directory.parent.is_dir():
        return None
    siblings = [p for p in sorted(directory.parent.iterdir()) if p.is_dir() and p.resolve() != directory.resolve()]
    names = [Path(entry.run_dir)]
    if entry.config is not None:  # a sibling made before config identity 3 holds it under an older hash
        names += [names[0].parent / name for name in folder_names(entry.train_config())]
    return next((p / name for p in siblings for name in names if (p / name / RESULTS).is_file()), None)


def share_finished_runs(experiment: Experiment) -> list[tuple[str, str]]:
    """Link each run finished in a sibling experiment (finished_elsewhere) into this one with a
    relative symlink, so it is read, not trained again. Returns (run name, message) pairs."""
    directory = Path(experiment.directory)
    linked = []
    for entry in experiment.runs:
        donor = finished_elsewhere(entry, directory)
        if donor is not None:
            folder = entry.folder(directory)
            folder.parent.mkdir(parents=True, exist_ok=True)
            os.symlink(os.path.relpath(donor, folder.parent), folder)
            linked.append((entry.name, f"finished in {donor.relative_to(directory.parent)}, shared"))
    return linked


def run_experiment(
    experiment: Experiment,
    executor: str = "local",
    parallel: int | None = None,
    ray_address: str | None = None,
    on_outcome: Callable[[RunOutcome], None] = lambda outcome: None,
) -> list[RunOutcome]:
    """Run every unfinished run of the experiment; one outcome per run, in completion order."""
    if executor not in EXECUTORS:
        raise ConfigError(f"unknown executor '{executor}' (choose from {', '.join(EXECUTORS)})")
    parallel = default_parallel() if parallel is None else parallel
    if parallel < 1:
        raise ConfigError(f"--parallel must be >= 1, got {parallel}")
    directory = experiment.directory
    shared = dict(share_finished_runs(experiment))
    skipped = [
        RunOutcome(r.name, "skipped", 0.0, str(log_path(directory, r)), shared.get(r.name, ""))
        for r in experiment.runs
        if r.is_done(directory)
    ]
    for outcome in skipped:
        on_outcome(outcome)
    pending = [r for r in experiment.runs if not r.is_done(directory)]
    todo = distinct_runs(pending)
    if not todo:
        return skipped
    if executor == "ray":
        trained = run_ray(todo, directory, parallel, on_outcome, address=ray_address)
    else:
        trained = run_local(todo, directory, parallel, on_outcome)
    return skipped + trained + _twin_outcomes(pending, todo, trained, directory, on_outcome)


def _twin_outcomes(pending: list[RunEntry], todo: list[RunEntry], trained: list[RunOutcome], directory: Path,
                   on_outcome: Callable[[RunOutcome], None]) -> list[RunOutcome]:  # fmt: skip
    """An outcome for each entry trained as another's run (an SDE row at lambda 0, the CfC's run): its twin's."""
    by_folder = {entry.run_dir: outcome for entry, outcome in _paired(todo, trained)}
    outcomes = []
    trained_names = {entry.name for entry in todo}
    for entry in pending:
        if entry.name in trained_names:
            continue
        twin = by_folder[entry.run_dir]
        outcome = RunOutcome(entry.name, twin.status, 0.0, twin.log, f"the same run as {twin.name}: trained once")
        outcomes.append(outcome)
        on_outcome(outcome)
    return outcomes


def _paired(entries: list[RunEntry], outcomes: list[RunOutcome]) -> list[tuple[RunEntry, RunOutcome]]:
    by_name = {outcome.name: outcome for outcome in outcomes}
    return [(entry, by_name[entry.name]) for entry in entries]
