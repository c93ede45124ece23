"""`liquidgs bench acceptance`: the GPU acceptance in stages, for a lent GPU machine's limits.

The machine (an H200) is lent for 15 minutes of device time in all: its start (about 3 minutes),
every command (at most 10 minutes each), the transfers and every idle wait counted. Only what a
command writes into its output folder comes back (8 files, 16 MiB each, two folders deep). So the
acceptance is one command that ends on its own well inside 10 minutes (COMMAND_BUDGET_S), runs
its stages one after another, each a subprocess under its own time limit, and appends one JSON
line per event to OUT/acceptance.jsonl, flushed and synced as it goes: a stage killed at its
limit (or the whole command killed) leaves every record before it, and `summary` names the stage
that did not finish.

Stages (STAGES; `--dry-run` prints the plan with its times):
  setup         CUDA torch sees a GPU; the scene is there at 800x800 (else one line, exit 2)
  gsplat-build  gsplat's CUDA kernels JIT-built in the background (timed) while `fields` runs
  fields        MLP, CfC, SDE-LNN, HexPlane: `liquidgs train` on CUDA (torch backend), and the
                same runs on the CPU at once: PSNR within FIELD_PSNR_MARGIN_DB of each other
  backends      gsplat against the torch backend on the scene's test cameras at 800x800: images
                and gradients within BACKEND_TOLERANCES (skipped, and said, without gsplat)
  scene         `liquidgs bench gpu`: the MLP on the scene at 800x800 for the time left: it/s,
                PSNR at the iteration reached, render FPS with the field, peak GPU memory
Plan B: when gsplat does not build, or its build would leave the scene stage too little time,
the scene stage trains with the torch backend on CUDA, labelled so (scene_backend).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from liquidgs.atomic import write_text_atomic
from liquidgs.errors import ConfigError, DataError
from liquidgs.settings import ArgumentParser, describe, matches

RECORDS = "acceptance.jsonl"
SUMMARY = "summary.txt"
BUILD_LOG = "gsplat-build.log"

# The lent machine's limits (the device tool's README) and this plan's margins.
DEVICE_BUDGET_S = 900
"""15 minutes of device time per session, the machine's start included."""
MACHINE_START_S = 180
"""What the plan allows for the machine's start (measured starts took 1-3 minutes)."""
TRANSFER_S = 30
"""Sending the working tree (about 40 MiB with the carried scene and wheels) and the files back."""
COMMAND_LIMIT_S = 600
"""The device tool kills a command at 10 minutes."""
COMMAND_BUDGET_S = 570
"""The acceptance ends on its own by then, 30 s inside the command limit, with its summary written."""
STAGE_LIMIT_S = 540
"""No stage may run longer than 9 minutes."""
SCENE_SIZE = 800
"""D-NeRF's full resolution: the scene must be 800x800."""

FIELDS = ("mlp", "cfc", "sde", "hexplane")
FIELD_DOWNSCALE = 8
"""The field stage trains at 100x100: a few hundred iterations take seconds on the GPU and about
half a minute per run on a CPU core, so the CPU twins finish inside the stage."""
FIELD_SCHEDULE = {
    "iterations": 300,
    "warmup": 50,
    "optim.means-lr-steps": 300,
    "optim.field-lr-steps": 300,
    "densify.start": 50,
    "densify.stop": 250,
    "eval.fps-frames": 10,
}
"""stress-mini's schedule (experiments/spec.py STRESS_MINI_OVERRIDES) on the tiny preset."""
FIELD_PSNR_MARGIN_DB = 1.0
"""The same run on CPU and on GPU: final test PSNR within this. Float summation order differs
between the devices, so the runs are not bit-equal and drift apart as two seeds do: seeds 0 and 1
of the MLP run differ by 0.36 dB (30.72 / 30.36 dB, measured on the 2-core CPU), so the margin is
about three times that."""
CPU_TWIN_THREADS = 3
"""Torch threads per CPU twin: four twins on the 16-core machine, beside the gsplat build."""

BACKEND_GAUSSIANS = 60_000
BACKEND_CAMERAS = 4
BACKEND_TOLERANCES = {"image_max_abs": 1e-3, "gradient_rel_l2": 1e-2}
"""gsplat against the torch backend: rgb and alpha per pixel within 1e-3 (8-bit images step by
4e-3), and each parameter's gradient within 1% in relative L2 norm (the two sum the same terms
in a different order; gsplat's own tests hold its kernels to its PyTorch reference at 1e-3 to
5e-1 per element, tests/test_render.py CUDA_TOLERANCES)."""

SCENE_MIN_S = 120
"""The scene stage's least time: a minute of training, then evaluation and the FPS timing."""
SCENE_EVAL_S = 60
"""Of the scene stage's time, what evaluation (the test views, LPIPS) and the FPS timing take."""


@dataclass(frozen=True)
class Stage:
    name: str
    limit_s: int
    """Killed at this (the scene stage: the time left, at most STAGE_LIMIT_S)."""
    expected_s: int
    proves: str


STAGES = (
    Stage("setup", 60, 15, "CUDA torch sees a GPU; the scene is there at 800x800"),
    Stage("gsplat-build", 300, 180, "gsplat's CUDA kernels built (in the background, beside fields), timed"),
    Stage("fields", 240, 150, f"{', '.join(FIELDS)}: `liquidgs train` {FIELD_SCHEDULE['iterations']} iterations "
          f"on CUDA; the same runs on CPU within {FIELD_PSNR_MARGIN_DB} dB PSNR"),  # fmt: skip
    Stage("backends", 90, 45, f"gsplat vs torch on {BACKEND_CAMERAS} test cameras at 800x800, "
          f"{BACKEND_GAUSSIANS:,} Gaussians: images and gradients; then `pytest -m cuda tests`"),  # fmt: skip
    Stage("scene", STAGE_LIMIT_S, 0, "MLP at 800x800 for the time left: it/s, PSNR, render FPS, peak memory"),
)
STAGE = {stage.name: stage for stage in STAGES}


def stage_plan(budget_s: int = COMMAND_BUDGET_S) -> list[tuple[str, int, int, str]]:
    """(stage, planned start, planned end, what) in seconds from the command's start, at every
    stage's limit: the build runs beside `fields`, `backends` waits for both."""
    setup_end = STAGE["setup"].limit_s
    build_end = setup_end + STAGE["gsplat-build"].limit_s
    fields_end = setup_end + STAGE["fields"].limit_s
    backends_start = max(build_end, fields_end)
    scene_start = backends_start + STAGE["backends"].limit_s
    return [
        ("setup", 0, setup_end, STAGE["setup"].proves),
        ("gsplat-build", setup_end, build_end, STAGE["gsplat-build"].proves),
        ("fields", setup_end, fields_end, STAGE["fields"].proves),
        ("backends", backends_start, scene_start, STAGE["backends"].proves),
        ("scene", scene_start, budget_s, STAGE["scene"].proves),
    ]


def plan_lines(budget_s: int = COMMAND_BUDGET_S) -> list[str]:
    plan = stage_plan(budget_s)
    scene_s = plan[-1][2] - plan[-1][1]
    total = MACHINE_START_S + TRANSFER_S + budget_s
    lines = [f"{name:<13} {start:>4}-{end:<4} s  {what}" for name, start, end, what in plan]
    lines += [
        f"scene stage: {scene_s} s at the least ({scene_s - SCENE_EVAL_S} s training, {SCENE_EVAL_S} s evaluation"
        f" and FPS); more when the stages before it end early (expected: {sum_expected()} s for them)",
        f"device time: {MACHINE_START_S} s machine start + {budget_s} s command + {TRANSFER_S} s transfers "
        f"= {total} s of the {DEVICE_BUDGET_S} s lent ({DEVICE_BUDGET_S - total} s spare); the command ends "
        f"{COMMAND_LIMIT_S - budget_s} s inside its {COMMAND_LIMIT_S} s limit; no stage over {STAGE_LIMIT_S} s",
    ]
    return lines


def sum_expected() -> int:
    build_or_fields = max(STAGE["gsplat-build"].expected_s, STAGE["fields"].expected_s)
    return STAGE["setup"].expected_s + build_or_fields + STAGE["backends"].expected_s


def check_plan(budget_s: int = COMMAND_BUDGET_S) -> None:
    """The plan fits the machine's limits, or one line saying where it does not."""
    plan = stage_plan(budget_s)
    too_long = [name for name, start, end, _ in plan if end - start > STAGE_LIMIT_S]
    if too_long:
        raise ConfigError(f"stage {too_long[0]} would run over {STAGE_LIMIT_S} s")
    if plan[-1][2] - plan[-1][1] < SCENE_MIN_S:
        raise ConfigError(f"--budget-s {budget_s} leaves the scene stage under {SCENE_MIN_S} s")
    if budget_s > COMMAND_LIMIT_S - 15 or MACHINE_START_S + TRANSFER_S + budget_s > DEVICE_BUDGET_S:
        raise ConfigError(f"--budget-s {budget_s} does not fit the {COMMAND_LIMIT_S} s command limit "
                          f"and {DEVICE_BUDGET_S} s of device time with a {MACHINE_START_S} s start")  # fmt: skip


# ----------------------------------------------------------------------------- plan B
@dataclass(frozen=True)
class BuildOutcome:
    state: str
    """'built', 'failed' (the build or the import raised), 'running' (not done yet), 'cut' (stopped)."""
    seconds: float | None = None
    detail: str = ""


def build_wait_s(seconds_left: float) -> float:
    """How long the acceptance may still wait for gsplat's build once `fields` is done: what
    leaves the backend stage its limit and the scene stage its least time."""
    return max(0.0, seconds_left - STAGE["backends"].limit_s - SCENE_MIN_S)


def scene_backend(build: BuildOutcome) -> tuple[str, str]:
    """The rasteriser the scene stage trains with, and the label saying why: gsplat once it built,
    else (plan B) our torch backend on CUDA."""
    if build.state == "built":
        return "gsplat", f"gsplat (kernels built in {build.seconds:.0f} s)"
    if build.state == "failed":
        return "torch", f"torch backend on CUDA (plan B: gsplat did not build: {build.detail})"
    if build.state == "cut":
        return "torch", (f"torch backend on CUDA (plan B: gsplat's build was stopped after {build.seconds:.0f} s "
                         "to leave the scene stage its time)")  # fmt: skip
    raise ValueError(f"the scene stage's backend is decided once the build is over, not while it is {build.state!r}")


# ----------------------------------------------------------------------------- records
def append_record(out_dir: Path, record: dict) -> None:
    """One JSON line, on disk before this returns: a kill a moment later keeps it."""
    with (Path(out_dir) / RECORDS).open("a") as file:
        file.write(json.dumps(record) + "\n")
        file.flush()
        os.fsync(file.fileno())


SUMMARY_FIELDS = {"stage": str, "event": str, "status": str, "seconds": float, "detail": str, "finished": bool,
                  "line": str}  # fmt: skip
"""The fields of a record that the summary reads, with their types (the others are left as they are)."""


def read_records(out_dir: Path) -> list[dict]:
    """The records; a last line cut by a kill mid-write is left out. A record that is not an object
    of the fields the summary reads, each of its type (SUMMARY_FIELDS), is one DataError naming the
    file, the line and the field."""
    path = Path(out_dir) / RECORDS
    if not path.is_file():
        return []
    records = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        if not isinstance(record, dict):
            raise DataError(path, f"line {number} is not a JSON object of record fields, got {record!r}")
        for key, kind in SUMMARY_FIELDS.items():
            if key in record and not matches(record[key], kind):
                raise DataError(path, f"line {number}: must be {describe(kind)}, got {record[key]!r}", key)
        if record.get("event") == "end" and "status" not in record:
            raise DataError(path, f"line {number}: an end record needs a status", "status")
        records.append(record)
    return records


def summary_lines(records: list[dict]) -> list[str]:
    """Per stage: passed / failed / did not finish / not started, with its figures."""
    by_stage: dict[str, list[dict]] = {}
    for record in records:
        by_stage.setdefault(record.get("stage", "?"), []).append(record)
    lines, unfinished = [], []
    for stage in STAGES:
        events = by_stage.get(stage.name, [])
        started = any(r.get("event") == "start" for r in events)
        end = next((r for r in reversed(events) if r.get("event") == "end"), None)
        if not started:
            lines.append(f"{stage.name}: not started")
            continue
        if end is None:
            unfinished.append(stage.name)
            lines.append(f"{stage.name}: DID NOT FINISH (killed, or the command was cut off); records before it stand")
            continue
        if end.get("finished") is False:
            unfinished.append(stage.name)
        lines.append(f"{stage.name}: {end['status']} in {end.get('seconds', 0):.0f} s"
                     + (f" - {end['detail']}" if end.get("detail") else ""))  # fmt: skip
        lines += [f"  {r['line']}" for r in events if r.get("event") == "result" and r.get("line")]
    verdict = (f"did not finish: {', '.join(unfinished)}" if unfinished else "every started stage finished")
    return [*lines, verdict]


# ----------------------------------------------------------------------------- the stages
def check_cuda() -> str:
    import torch

    if not torch.cuda.is_available():
        raise ConfigError("no CUDA GPU: this torch sees none (the acceptance needs a GPU machine; --dry-run: any)")
    return torch.cuda.get_device_name()


def check_scene(scene: Path, size: int = SCENE_SIZE) -> tuple[int, int, int]:
    """(width, height, test views) of the scene at downscale 1, or one line saying what is wrong."""
    from liquidgs.data import DataConfig, load_dataset

    if not (Path(scene) / "transforms_train.json").is_file():
        raise ConfigError(f"{scene}: no D-NeRF scene there (no transforms_train.json; scripts/gpu_prepare.sh "
                          "copies one into .scene/)")  # fmt: skip
    dataset = load_dataset(DataConfig(path=Path(scene), cache_images=0))
    camera = (dataset.test or dataset.train)[0].camera
    if (camera.width, camera.height) != (size, size):
        raise ConfigError(f"{scene}: images are {camera.width}x{camera.height}, the acceptance needs {size}x{size}")
    return camera.width, camera.height, len(dataset.test)


def field_train_args(scene: Path, field: str, device: str, out: Path) -> list[str]:
    """The `liquidgs train` command line of one field run (CPU and GPU alike, but for --device)."""
    flags = [f"--{key}={value}" for key, value in FIELD_SCHEDULE.items()]
    return ["train", "--data", str(scene), "--preset", "tiny", "--downscale", str(FIELD_DOWNSCALE), "--field", field,
            "--seed", "0", "--device", device, "--backend", "torch", "--eval.lpips-backbone", "alex", *flags,
            "--out", str(out)]  # fmt: skip


def field_verdict(field: str, gpu: dict | None, cpu: dict | None) -> dict:
    """One field's CPU-vs-GPU record from the two runs' results (None: the run did not finish)."""
    record = {"field": field, "gpu_psnr": gpu and gpu["psnr"], "cpu_psnr": cpu and cpu["psnr"],
              "gpu_seconds": gpu and gpu["seconds"], "margin_db": FIELD_PSNR_MARGIN_DB}  # fmt: skip
    if gpu is None or cpu is None:
        missing = " and ".join(d for d, r in (("GPU", gpu), ("CPU", cpu)) if r is None)
        return record | {"passed": False, "line": f"{field}: FAIL - the {missing} run did not finish"}
    difference = gpu["psnr"] - cpu["psnr"]
    passed = math.isfinite(difference) and abs(difference) <= FIELD_PSNR_MARGIN_DB
    line = (f"{field}: {'pass' if passed else 'FAIL'} - GPU {gpu['psnr']:.2f} dB in {gpu['seconds']:.0f} s, "
            f"CPU {cpu['psnr']:.2f} dB, difference {difference:+.2f} dB (margin {FIELD_PSNR_MARGIN_DB} dB)")
    return record | {"difference_db": difference, "passed": passed, "line": line}


def _run_result(run_dir: Path, seconds: float) -> dict | None:
    results = run_dir / "results.json"
    if not results.is_file():
        return None
    return {"psnr": json.loads(results.read_text())["final"]["psnr"], "seconds": round(seconds, 1)}


def run_fields(args: argparse.Namespace) -> bool:
    work = Path(args.work) / "fields"
    cli = [sys.executable, "-m", "liquidgs.cli"]
    cpu_env = {**os.environ, "OMP_NUM_THREADS": str(CPU_TWIN_THREADS), "CUDA_VISIBLE_DEVICES": ""}
    work.mkdir(parents=True, exist_ok=True)
    twins, started = {}, {}
    for field in FIELDS:  # the CPU twins run beside the GPU runs
        started[field] = time.perf_counter()
        with (work / f"{field}-cpu.log").open("w") as log:
            twins[field] = subprocess.Popen([*cli, *field_train_args(args.scene, field, "cpu", work / f"{field}-cpu")],
                                            env=cpu_env, stdout=log, stderr=subprocess.STDOUT)  # fmt: skip
    gpu_results = {}
    for field in FIELDS:
        began = time.perf_counter()
        with (work / f"{field}-cuda.log").open("w") as log:
            subprocess.run([*cli, *field_train_args(args.scene, field, "cuda", work / f"{field}-cuda")],
                           stdout=log, stderr=subprocess.STDOUT, check=False)  # fmt: skip
        gpu_results[field] = _run_result(work / f"{field}-cuda", time.perf_counter() - began)
        append_record(args.out, {"stage": "fields", "event": "run", "field": field, "device": "cuda",
                                 "result": gpu_results[field]})  # fmt: skip
    passed = True
    for field in FIELDS:
        twins[field].wait()
        cpu = _run_result(work / f"{field}-cpu", time.perf_counter() - started[field])
        verdict = field_verdict(field, gpu_results[field], cpu)
        append_record(args.out, {"stage": "fields", "event": "result", **verdict})
        passed &= verdict["passed"]
    return passed


def relative_l2(ours, theirs) -> float:
    return float((ours - theirs).norm() / theirs.norm().clamp_min(1e-30))


def run_backends(args: argparse.Namespace) -> bool:
    import torch

    from liquidgs.data import DataConfig, load_dataset
    from liquidgs.gaussians.model import activate, init_random_box
    from liquidgs.render import rasterize

    dataset = load_dataset(DataConfig(path=args.scene, cache_images=0))
    generator = torch.Generator().manual_seed(0)
    params = init_random_box(BACKEND_GAUSSIANS, 1.3, sh_degree=3, seed=0, device="cuda")
    with torch.no_grad():  # a scene with visible structure: small Gaussians, varied opacity and colour
        params["scales"].copy_(torch.empty(BACKEND_GAUSSIANS, 3).uniform_(-5.5, -3.5, generator=generator))
        params["opacities"].copy_(torch.empty(BACKEND_GAUSSIANS, 1).uniform_(-2, 2, generator=generator).view_as(
            params["opacities"]))  # fmt: skip
        params["sh0"].copy_(torch.randn(params["sh0"].shape, generator=generator))
        params["shN"].copy_(0.2 * torch.randn(params["shN"].shape, generator=generator))
    passed = True
    for index, frame in enumerate((dataset.test or dataset.train)[:BACKEND_CAMERAS]):
        weights = torch.randn(frame.camera.height, frame.camera.width, 4, generator=generator).cuda()
        outputs = {}
        for backend in ("torch", "gsplat"):
            leaves = {key: value.detach().clone().requires_grad_(True) for key, value in params.items()}
            inputs = activate(leaves)
            camera = frame.camera
            out = rasterize(inputs["means"], inputs["quats"], inputs["scales"], inputs["opacities"],
                            inputs["colors"], camera.viewmat.cuda(), camera.K.cuda(), camera.width, camera.height,
                            sh_degree=3, backend=backend)  # fmt: skip
            (torch.cat([out.rgb, out.alpha], dim=-1) * weights).sum().backward()
            outputs[backend] = (out, {key: leaf.grad for key, leaf in leaves.items()})
        (ours, our_grads), (theirs, their_grads) = outputs["torch"], outputs["gsplat"]
        image = max(float((ours.rgb - theirs.rgb).abs().max()), float((ours.alpha - theirs.alpha).abs().max()))
        gradients = {key: relative_l2(our_grads[key], their_grads[key]) for key in their_grads}
        ok = image <= BACKEND_TOLERANCES["image_max_abs"] and max(gradients.values()) <= BACKEND_TOLERANCES[
            "gradient_rel_l2"]  # fmt: skip
        worst = max(gradients, key=gradients.get)
        line = (f"camera {index} ({frame.name}): {'pass' if ok else 'FAIL'} - image max |diff| {image:.2e} "
                f"(<= {BACKEND_TOLERANCES['image_max_abs']:g}), worst gradient {worst} {gradients[worst]:.2e} "
                f"relative L2 (<= {BACKEND_TOLERANCES['gradient_rel_l2']:g})")
        append_record(args.out, {"stage": "backends", "event": "result", "camera": frame.name, "passed": ok,
                                 "image_max_abs": image, "gradient_rel_l2": gradients, "line": line})  # fmt: skip
        passed &= ok
    return passed


def run_cuda_tests(args: argparse.Namespace) -> bool:
    """`pytest -m cuda tests`: every test module collects without the dev extras (tests/test_collection.py)."""
    root = Path(__file__).resolve().parents[3]
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-m", "cuda", "-p", "no:cacheprovider", "tests"],
                          cwd=root, capture_output=True, text=True, check=False)  # fmt: skip
    tail = (done.stdout.strip().splitlines() or ["(no output)"])[-1]
    append_record(args.out, {"stage": "backends", "event": "result", "passed": done.returncode == 0,
                             "line": f"pytest -m cuda: {'pass' if done.returncode == 0 else 'FAIL'} - {tail}"})
    return done.returncode == 0


STAGE_RUNNERS = {
    "fields": run_fields,
    "backends": lambda args: all([run_backends(args), run_cuda_tests(args)]),
}
BUILD_CODE = """
import os, time, torch
major, minor = torch.cuda.get_device_capability()
os.environ.setdefault("TORCH_CUDA_ARCH_LIST", f"{major}.{minor}")  # the one GPU present: one architecture
began = time.perf_counter()
from gsplat.cuda._backend import _C
assert _C is not None, "gsplat found no CUDA toolkit"
print(f"gsplat kernels ready in {time.perf_counter() - began:.1f} s", flush=True)
"""


# ----------------------------------------------------------------------------- the command
class Acceptance:
    """Runs the stages in order under one deadline, writing each stage's start and end records."""

    def __init__(self, args: argparse.Namespace):
        self.args = args
        self.out = Path(args.out)
        self.began = time.monotonic()
        self.deadline = self.began + args.budget_s

    def left(self) -> float:
        return self.deadline - time.monotonic()

    def record(self, stage: str, event: str, **fields) -> None:
        append_record(self.out, {"stage": stage, "event": event, "t": round(time.monotonic() - self.began, 1),
                                 **fields})  # fmt: skip

    def end(self, stage: str, began: float, status: str, finished: bool = True, detail: str = "") -> None:
        self.record(stage, "end", status=status, finished=finished, seconds=round(time.monotonic() - began, 1),
                    detail=detail)  # fmt: skip

    def run_stage(self, stage: str, command: list[str], limit_s: float, env: dict | None = None) -> bool:
        """`command` as its own process group, killed with its children at `limit_s`."""
        began = time.monotonic()
        self.record(stage, "start", limit_s=round(limit_s))
        process = subprocess.Popen(command, start_new_session=True, env=env)
        try:
            rc = process.wait(timeout=max(1.0, limit_s))
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
            self.end(stage, began, f"killed at its {limit_s:.0f} s limit", finished=False)
            return False
        self.end(stage, began, "passed" if rc == 0 else f"failed (exit {rc})")
        return rc == 0

    def stage_command(self, stage: str) -> list[str]:
        a = self.args
        return [sys.executable, "-m", "liquidgs.cli", "bench", "acceptance", "--stage", stage, "--out", str(a.out),
                "--scene", str(a.scene), "--work", str(a.work), "--size", str(a.size)]  # fmt: skip

    def start_build(self) -> subprocess.Popen:
        self.build_began = time.monotonic()
        self.record("gsplat-build", "start", limit_s=STAGE["gsplat-build"].limit_s)
        env = {**os.environ, "TORCH_EXTENSIONS_DIR": str(Path(self.args.build_dir).resolve()),
               "MAX_JOBS": str(os.cpu_count() or 8)}  # fmt: skip
        Path(self.args.work).mkdir(parents=True, exist_ok=True)
        with (Path(self.args.work) / BUILD_LOG).open("w") as log:
            return subprocess.Popen([sys.executable, "-c", BUILD_CODE], env=env, stdout=log,
                                    stderr=subprocess.STDOUT, start_new_session=True)  # fmt: skip

    def finish_build(self, build: subprocess.Popen) -> BuildOutcome:
        own_limit = self.build_began + STAGE["gsplat-build"].limit_s - time.monotonic()
        try:
            rc = build.wait(timeout=max(0.0, min(own_limit, build_wait_s(self.left()))))
        except subprocess.TimeoutExpired:
            os.killpg(build.pid, signal.SIGKILL)
            build.wait()
            rc = None
        seconds = time.monotonic() - self.build_began
        log = Path(self.args.work) / BUILD_LOG
        lines = log.read_text(errors="replace").splitlines() if log.is_file() else []
        (self.out / BUILD_LOG).write_text("\n".join(lines[-200:]) + "\n")  # the end of it comes back
        if rc is None:
            outcome = BuildOutcome("cut", seconds)
            self.end("gsplat-build", self.build_began, "stopped to leave the scene stage its time", finished=False)
            return outcome
        outcome = BuildOutcome("built" if rc == 0 else "failed", seconds, (lines or ["no output"])[-1][:200])
        self.end("gsplat-build", self.build_began, "passed" if rc == 0 else "failed", detail=outcome.detail)
        return outcome

    def run(self) -> int:
        a = self.args
        began = time.monotonic()
        self.record("setup", "start", limit_s=STAGE["setup"].limit_s)
        try:
            import torch

            gpu = check_cuda()
            width, height, views = check_scene(a.scene, a.size)
        except ConfigError as err:
            self.end("setup", began, "failed", detail=str(err))
            raise
        self.end("setup", began, "passed", detail=f"{gpu}, torch {torch.__version__}, scene {a.scene} "
                 f"{width}x{height} ({views} test views)")  # fmt: skip
        build = self.start_build()
        results = [self.run_stage("fields", self.stage_command("fields"), min(STAGE["fields"].limit_s, self.left()))]
        outcome = self.finish_build(build)
        if outcome.state == "built":
            limit = min(STAGE["backends"].limit_s, self.left() - SCENE_MIN_S)
            results.append(self.run_stage("backends", self.stage_command("backends"), limit))
        else:
            self.record("backends", "start", limit_s=0)
            self.end("backends", time.monotonic(), "skipped", detail="gsplat is not built: nothing to compare")
        backend, label = scene_backend(outcome)
        limit = min(STAGE_LIMIT_S, self.left())
        scene = [sys.executable, "-m", "liquidgs.cli", "bench", "gpu", "--data", str(a.scene), "--backend", backend,
                 "--backend-label", label, "--budget-s", f"{max(10.0, limit - SCENE_EVAL_S):.0f}",
                 "--output", str(self.out / RECORDS), "--out", str(Path(a.work) / "scene")]  # fmt: skip
        env = {**os.environ, "TORCH_EXTENSIONS_DIR": str(Path(a.build_dir).resolve())}
        results.append(self.run_stage("scene", scene, limit, env=env))
        lines = summary_lines(read_records(self.out))
        write_text_atomic(self.out / SUMMARY, "\n".join(lines) + "\n")
        print("\n".join(lines), flush=True)
        return 0 if all(results) else 1


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="liquidgs bench acceptance", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="output folder: records, summary, build log")
    parser.add_argument("--scene", type=Path, default=Path(".scene/hellwarrior"), help="D-NeRF scene at 800x800")
    parser.add_argument("--size", type=int, default=SCENE_SIZE, help="the scene's width and height (default 800)")
    parser.add_argument("--budget-s", type=int, default=COMMAND_BUDGET_S, help="seconds the command may take")
    parser.add_argument("--work", type=Path, default=Path("/tmp/liquidgs-acceptance"), help="runs and logs")
    parser.add_argument("--build-dir", type=Path, default=Path(".gsplat-build"),
                        help="gsplat's build (TORCH_EXTENSIONS_DIR; ignored by git, so a warm machine keeps it)")
    parser.add_argument("--dry-run", action="store_true", help="check the scene, print the stage plan")
    parser.add_argument("--summary", action="store_true", help="print the summary of the records in --out")
    parser.add_argument("--stage", choices=sorted(STAGE_RUNNERS), help=argparse.SUPPRESS)
    return parser


def run(args: argparse.Namespace) -> int:
    if args.summary:
        print("\n".join(summary_lines(read_records(args.out))))
        return 0
    if args.stage:
        return 0 if STAGE_RUNNERS[args.stage](args) else 1
    check_plan(args.budget_s)
    if args.dry_run:
        width, height, views = check_scene(args.scene, args.size)
        print(f"scene {args.scene}: {width}x{height}, {views} test views; records to {args.out / RECORDS}")
        print("\n".join(plan_lines(args.budget_s)))
        return 0
    check_cuda()  # before anything is written: no GPU is one line
    args.out.mkdir(parents=True, exist_ok=True)
    return Acceptance(args).run()
