"""`liquidgs data synth` and `liquidgs data check`, end to end through the CLI entry point."""

from __future__ import annotations

from liquidgs import cli
from liquidgs.data import DEFAULT_SYNTHETIC_SCENE


def test_synth_then_check_both_layouts(tmp_path, capsys):
    out = tmp_path / "scene"
    args = [
        "data",
        "synth",
        "--scene",
        DEFAULT_SYNTHETIC_SCENE,
        "--out",
        str(out),
        "--size",
        "24",
        "--frames",
        "16",
    ]
    assert cli.main([*args, "--seed", "1"]) == 0
    printed = capsys.readouterr().out
    assert str(out / "dnerf") in printed and str(out / "nerfies") in printed

    assert cli.main(["data", "check", str(out / "dnerf")]) == 0
    report = capsys.readouterr().out
    assert "format:     dnerf (synthetic)" in report
    assert "frames:     train 12, test 2, val 2" in report
    assert "resolution: train 24x24" in report and "fx 33.333" in report
    assert "time:       train [0.0000, 1.0000]" in report
    assert "images:     16 decoded in full" in report

    assert cli.main(["data", "check", str(out / "nerfies"), "--format", "nerfies", "--split", "interp"]) == 0
    report = capsys.readouterr().out
    assert "format:     nerfies (real)" in report and "frames:     train 4, test 4" in report
    assert "resolution: train 12x12" in report and "points:     4096" in report


def test_usage_errors_exit_nonzero_in_one_line(tmp_path, capsys):
    assert cli.main(["data", "synth", "--scene", "nope", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown synthetic scene 'nope'" in err
    assert cli.main(["data", "synth", "--scene", DEFAULT_SYNTHETIC_SCENE]) == 2  # --out is required
    capsys.readouterr()
    assert cli.main(["data", "check", str(tmp_path)]) == 2  # neither layout's files
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "neither transforms_train.json" in err and "Traceback" not in err
