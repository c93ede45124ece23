"""`liquidgs bench fields`: one JSON object per case, with the numbers the report quotes."""

import json

import pytest
import torch

from liquidgs.errors import ConfigError
from liquidgs.fields import field_names
from liquidgs.fields.benchmark import VARIANTS, main


@pytest.fixture(autouse=True)
def restore_threads():
    """--threads changes a process-wide torch setting; put it back for the other tests."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


def test_json_rows_cover_every_field_and_size(capsys):
    argv = ["--json", "--sizes", "64,128", "--presets", "tiny", "--variants", "--repeats", "1"]
    argv += ["--threads", "1"]
    assert main(argv) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    labels = list(field_names()) + list(VARIANTS)
    assert [(r["field"], r["gaussians"]) for r in rows] == [(f, n) for f in labels for n in (64, 128)]
    for row in rows:
        assert row["device"] == "cpu" and row["torch"] and row["threads"] == 1 and row["preset"] == "tiny"
        assert row["forward_gaussians_per_s"] > 0
        if row["field"] == "static":
            assert row["params"] == 0 and row["forward_backward_gaussians_per_s"] is None
        else:
            assert row["params"] > 0 and row["forward_backward_gaussians_per_s"] > 0
            # Nearly every parameter of a network field is multiplied once per Gaussian; a grid's
            # are looked up (4 corners of 6 planes), which FLOPs do not count.
            network_share = 0.01 if row["field"] == "hexplane" else 0.9
            assert row["flops_per_gaussian"] > 2 * row["params"] * network_share
        assert row["lambda"] == (0.05 if row["field"].startswith("sde") else 0.0)


def test_table_output_and_bad_arguments(capsys):
    assert main(["--sizes=32", "--presets=tiny", "--fields=mlp", "--repeats=1", "--threads=1"]) == 0
    assert "mlp" in capsys.readouterr().out
    with pytest.raises(ConfigError, match="unknown field"):
        main(["--fields", "nerf"])
    with pytest.raises(ConfigError, match="unknown preset"):
        main(["--presets", "blender", "--sizes", "8"])
    with pytest.raises(ConfigError, match="sizes"):
        main(["--sizes", "0"])
