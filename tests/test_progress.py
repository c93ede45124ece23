"""Progress a background job's log can follow (commands.progress): plain lines where the output is
not a terminal, with counts, loss, PSNR, Gaussians, elapsed time and ETA, and the evaluations named."""

from __future__ import annotations

import re

from liquidgs.commands import progress
from tiny_runs import run_cli, tiny_flags

LINE = re.compile(
    r"^train (\d+)/40  loss (nan|\d+\.\d{4})  PSNR (nan|\d+\.\d\d)  Gaussians [\d,]+  "
    r"elapsed \d+:\d\d:\d\d  ETA (-|\d+:\d\d:\d\d)$"
)


def test_train_into_a_file_prints_plain_progress_lines_at_its_interval(puppet_scene, tmp_path, monkeypatch):
    monkeypatch.setattr(progress, "PLAIN_INTERVAL_S", 0.0)  # every step, so the test sees many
    code, _, err = run_cli(
        ["train", "--data", str(puppet_scene), "--field", "mlp", *tiny_flags(), "--out", str(tmp_path / "a")]
    )
    assert code == 0, err
    lines = err.splitlines()
    steps = [int(m[1]) for m in map(LINE.match, lines) if m]
    assert steps == list(range(41)), lines[:5]  # the start, then every step (no bar redrawn)
    assert "\x1b[" not in err  # no terminal escapes in a log
    assert "evaluation at iteration 20 (2 test views)" in err
    assert "training done; the final evaluation of 2 test views starts" in err
    assert lines.index("evaluation at iteration 20 (2 test views)") < next(
        i for i, line in enumerate(lines) if line.startswith("train 21/40")
    )
    monkeypatch.setattr(progress, "PLAIN_INTERVAL_S", 3600.0)  # a short run: the start and the end only
    code, _, err = run_cli(
        ["train", "--data", str(puppet_scene), "--field", "mlp", *tiny_flags(), "--out", str(tmp_path / "b")]
    )
    assert code == 0, err
    assert [int(m[1]) for m in map(LINE.match, err.splitlines()) if m] == [0, 40]
