"""docs/experiments/real_clips_compare.py: the real-clip runs_folder's margins and their paired
comparisons, on runs written here with known scores."""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path

import pytest

from liquidgs.train.run_folder.provenance import source_record

ROOT = Path(__file__).resolve().parents[1]
ITERATIONS = 1500
MOVING = ["cat", "lady-running", "backpack", "teddy", "pillow"]


def load_script():
    spec = importlib.util.spec_from_file_location("real_clips_compare", ROOT / "docs/experiments/real_clips_compare.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def write_run(root: Path, spec: str, clip: str, field: str, seed: int, subject: float | None, epe: float | None = None,
              aligned: float = 25.0, iterations: int = ITERATIONS) -> None:  # fmt: skip
    run = root / spec / "real-clips" / clip / field / f"{field}{seed}{spec[-4:]}"
    run.mkdir(parents=True)
    (run / "checkpoint.pt").write_bytes(f"{spec} {clip} {field} {seed}".encode())
    results = {"seed": seed, "iterations": iterations, "final_aligned": {"psnr": aligned}}
    (run / "results.json").write_text(json.dumps(results))
    evaluated = {"iteration": iterations, "finished": True,
                 "source": source_record(run, "0123456789", iterations, run / "checkpoint.pt")}  # fmt: skip
    if subject is not None:
        (run / "eval.json").write_text(json.dumps({**evaluated, "masked_aligned": {"inside": {"psnr": subject}}}))
    if epe is not None:
        (run / "eval-auto.json").write_text(json.dumps({**evaluated, "flow_error": {"inside_masks_px": epe}}))


@pytest.fixture
def runs_folder(tmp_path):
    """Ten (clip, seed) pairs. Without evidence each field is 1 dB over a static model at 20 dB; with
    it, 1.5 dB more (+-0.1 by seed) over a static model at 21 dB; without the flow loss the field is
    at 21.5 (over no-evidence static: +1.5) and its end-point error is twice the evidence's."""
    for clip in MOVING:
        for seed in (0, 1):
            write_run(tmp_path, "experiment", clip, "static", seed, 20.0, epe=4.0)
            write_run(tmp_path, "experiment-motion", clip, "static", seed, 21.0, epe=3.0)
            for field in ("mlp", "cfc", "hexplane"):
                write_run(tmp_path, "experiment", clip, field, seed, 21.0, epe=2.0)
                write_run(tmp_path, "experiment-motion", clip, field, seed, 23.5 + (0.1 if seed else -0.1), epe=1.0)
                write_run(tmp_path, "experiment-motion-without-flow", clip, field, seed, 21.5, epe=2.0)
    write_run(tmp_path, "experiment", "apple", "static", 0, None, aligned=30.0)
    write_run(tmp_path, "experiment", "apple", "mlp", 0, None, aligned=30.25)
    return tmp_path


def test_the_evidence_gain_is_the_difference_of_margins_each_over_its_own_static_model(runs_folder):
    text = load_script().report(runs_folder)
    section = text.split("## Subject margin, the motion evidence against none")[1].split("##")[0]
    rows = [line for line in section.splitlines() if line.startswith("| mlp |")]
    # margins: with 23.5 +- 0.1 - 21 = +2.5 +- 0.1, without 21 - 20 = +1.0: the gain +1.50 on ten pairs
    assert rows and rows[0].startswith("| mlp | 10 | +1.50 | +1.") and "| helps |" in rows[0], rows


def test_an_ablation_without_its_own_static_model_is_measured_over_the_spec_its_comment_names(runs_folder):
    text = load_script().report(runs_folder)
    section = text.split("## Subject margin, with the flow loss against without it")[1].split("##")[0]
    row = next(line for line in section.splitlines() if line.startswith("| cfc |"))
    # without the flow loss: 21.5 over real-clips.yml's static (20.0) = +1.5; with: +2.5: +1.00
    assert row.startswith("| cfc | 10 | +1.00 |"), row
    assert "with the split against" not in text  # no without-split folder: that comparison is left out
    alone = text.split("## Subject margin, the split alone against neither piece")[1].split("##")[0]
    # the split alone (21.5) against neither (21.0), both over real-clips.yml's static model: +0.50
    assert next(line for line in alone.splitlines() if line.startswith("| mlp |")).startswith("| mlp | 10 | +0.50 |")


def test_end_point_error_change_and_still_clip_margins(runs_folder):
    text = load_script().report(runs_folder)
    section = text.split("## End-point error in the motion masks, the flow loss on against off")[1].split("##")[0]
    assert next(line for line in section.splitlines() if line.startswith("| hexplane |")).startswith(
        "| hexplane | 10 | -50% |"
    )
    assert "| experiment | apple | 0 | mlp | +0.25 |" in text


def test_each_specs_margins_and_the_doubled_schedule_against_the_quick_look(tmp_path):
    """Each spec's own subject margins (the bars are on them), and the 3,000-iteration spec's against
    the quick look's pair by pair and against no motion evidence at 3,000: the quick look's fields 3 dB
    over a static model at 20 dB, the doubled schedule's 4 dB (+-0.1 by seed) over one at 21 dB, and
    without the evidence 2.5 dB over one at 20.5 dB, their end-point errors 3.0 px against 2.0."""
    for clip in MOVING:
        for seed in (0, 1):
            write_run(tmp_path, "experiment-defaults", clip, "static", seed, 20.0)
            write_run(tmp_path, "experiment-defaults-3000", clip, "static", seed, 21.0, iterations=3000)
            write_run(tmp_path, "experiment-3000", clip, "static", seed, 20.5, iterations=3000)
            for field in ("mlp", "cfc", "hexplane"):
                write_run(tmp_path, "experiment-defaults", clip, field, seed, 23.0)
                write_run(tmp_path, "experiment-defaults-3000", clip, field, seed, 25.0 + (0.1 if seed else -0.1),
                          epe=2.0, iterations=3000)  # fmt: skip
                write_run(tmp_path, "experiment-3000", clip, field, seed, 23.0, epe=3.0, iterations=3000)
    text = load_script().report(tmp_path)
    margins = text.split("## Subject margin over the static model, each spec")[1].split("##")[0]
    assert "| experiment-defaults | cfc | 10 | +3.00 |" in margins
    row = next(line for line in margins.splitlines() if line.startswith("| experiment-defaults-3000 | hexplane |"))
    assert row.startswith("| experiment-defaults-3000 | hexplane | 10 | +4.00 | +3.9") and "cat s1 +4.10" in row, row
    longer = text.split("## Subject margin, 3,000 iterations against the quick look's 1,500")[1].split("##")[0]
    row = next(line for line in longer.splitlines() if line.startswith("| mlp |"))
    assert row.startswith("| mlp | 10 | +1.00 |") and "| helps |" in row, row
    evidence = text.split("## Subject margin, the motion evidence at the defaults against none, at 3")[1]
    row = next(line for line in evidence.split("##")[0].splitlines() if line.startswith("| cfc |"))
    assert row.startswith("| cfc | 10 | +1.50 |") and "| helps |" in row and "cat s1 +2.50 -> +4.10" in row, row
    epe = text.split("## End-point error in the motion masks, the motion evidence at the defaults against none, at")[1]
    row = next(line for line in epe.splitlines() if line.startswith("| hexplane |"))
    assert row.startswith("| hexplane | 10 | -33% |"), row


def test_two_finished_runs_of_one_clip_field_and_seed_are_refused(runs_folder):
    cell = runs_folder / "experiment/real-clips/cat/mlp"
    shutil.copytree(cell / "mlp0ment", cell / "another-hash")
    with pytest.raises(SystemExit, match="a second finished run of"):
        load_script().report(runs_folder)


def test_a_broken_results_file_is_one_line_naming_it(runs_folder):
    broken = next(runs_folder.glob("experiment/real-clips/cat/mlp/*/results.json"))
    broken.write_text("{ not json")
    with pytest.raises(SystemExit, match=f"{broken}: cannot be read as JSON"):
        load_script().report(runs_folder)


def test_an_evaluation_of_another_checkpoint_is_refused_in_one_line(runs_folder):
    """A run trained on after its evaluation (its checkpoint changed), or evaluated before it
    finished: its scores are not the run's, so the comparison stops naming the file."""
    run = runs_folder / "experiment-motion" / "real-clips" / "cat" / "mlp" / "mlp0tion"
    (run / "checkpoint.pt").write_bytes(b"trained on")
    changed = r"eval.json: derived from the checkpoint at iteration 1500, but .* has changed"
    with pytest.raises(SystemExit, match=changed):
        load_script().report(runs_folder)
    run = runs_folder / "experiment" / "real-clips" / "cat" / "cfc" / "cfc1ment"
    auto = json.loads((run / "eval-auto.json").read_text())
    (run / "eval-auto.json").write_text(json.dumps({**auto, "iteration": 600, "finished": False}))
    shutil.rmtree(runs_folder / "experiment-motion")
    with pytest.raises(SystemExit, match=r"eval-auto.json: evaluates iteration 600, not the finished run's 1500"):
        load_script().report(runs_folder)
