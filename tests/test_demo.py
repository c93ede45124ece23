"""The main command (`make demo`), end to end on a small scale."""

import imageio.v2 as imageio
import numpy as np
import pytest
from PIL import Image

from liquidgs.cli import main as cli
from shared_data import use_optional_lpips


@pytest.mark.slow
def test_demo_writes_the_report(tmp_path, monkeypatch, capsys):
    lpips_dir = use_optional_lpips(monkeypatch)
    out = tmp_path / "report"
    assert cli(["demo", "--out", str(out), "--size", "32", "--iterations", "30"]) == 0
    report = (out / "report.md").read_text()
    for label in ("Static", "D-3DGS (MLP)", "Liquid CfC", "SDE-LNN", "HexPlane (4D-GS)"):  # every registered field
        assert f"| {label} |" in report
    assert "| field | PSNR | moving-region PSNR |" in report and "of the test pixels" in report
    assert "**final**" in report and "Fastest-moving test frame" in report
    if lpips_dir:
        assert "LPIPS: LPIPS-Alex, v0.1, inputs scaled to [-1,1] (the paper names no backbone; the D-3DGS" in report
    else:
        assert "LPIPS-Alex unavailable: backbone weights not found" in report
    side_by_side = np.asarray(Image.open(out / "side_by_side.png"))
    assert side_by_side.shape[:2] == (128, 6 * 128)  # 32 px enlarged 4x: truth, static, MLP, CfC, SDE-LNN, HexPlane
    assert len(imageio.mimread(out / "sweep.mp4")) == 48
    # Each run trained as its own `liquidgs train` process, with its command and output in a log.
    logs = sorted((out / "logs").glob("*.log"))
    assert len(logs) == 5 and all("liquidgs.cli train" in log.read_text() for log in logs)
    assert f"report written to {out.resolve()}" in capsys.readouterr().err.replace("\n", "")
    # Finished runs are reused: a second demo trains nothing and rewrites the same table.
    first = report
    assert cli(["demo", "--out", str(out), "--size", "32", "--iterations", "30"]) == 0
    assert (out / "report.md").read_text() == first


def test_demo_refuses_a_bad_parallel_before_writing_anything(tmp_path, capsys):
    out = tmp_path / "report"
    assert cli(["demo", "--out", str(out), "--parallel", "0"]) == 2
    assert "--parallel must be >= 1, got 0" in capsys.readouterr().err
    assert not out.exists()
