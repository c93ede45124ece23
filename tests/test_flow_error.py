"""`eval --flow-error`: the end-point error of the Gaussians' rendered motion against measured flow."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from liquidgs.data.flow import FlowPair
from liquidgs.train.flow_loss import flow_error, rendered_flow
from test_flow_loss import HEIGHT, WIDTH, camera, two_gaussians


def test_the_error_is_zero_for_the_rendered_motion_and_the_offset_s_length_otherwise():
    frames = [SimpleNamespace(name="a", time=0.0, camera=camera()), SimpleNamespace(name="b", time=1.0,
              camera=camera(0.1))]  # fmt: skip
    shift = torch.tensor([[0.2, 0, 0], [0, -0.1, 0]], dtype=torch.float64)

    def at_time(time):
        return two_gaussians(shift * time)

    forward, _ = rendered_flow(at_time(0.0), frames[0].camera, at_time(1.0), frames[1].camera, backend="torch")
    backward, _ = rendered_flow(at_time(1.0), frames[1].camera, at_time(0.0), frames[0].camera, backend="torch")
    valid = np.ones((HEIGHT, WIDTH), bool)
    masks = np.zeros((2, HEIGHT, WIDTH), bool)
    masks[:, :, : WIDTH // 2] = True  # the left Gaussian's half

    def pair(offset):
        measured = [(f.numpy() + offset).astype(np.float32) for f in (forward, backward)]
        return FlowPair("a", "b", *measured, valid, valid)

    exact = flow_error(at_time, frames, [pair(0.0)], masks, backend="torch")
    assert exact["pairs"] == 1 and exact["consistent_px"] == pytest.approx(0.0, abs=1e-5)
    assert 0 < exact["inside_masks_pixels"] < exact["consistent_pixels"]
    off = flow_error(at_time, frames, [pair(np.array([3.0, 4.0]))], masks, backend="torch")
    assert off["consistent_px"] == pytest.approx(5.0, rel=1e-4)
    assert off["inside_masks_px"] == pytest.approx(5.0, rel=1e-4)
    other = FlowPair("x", "b", *(f.numpy() for f in (forward, backward)), valid, valid)  # "x" is no frame here
    skipped = flow_error(at_time, frames, [other], masks, backend="torch")
    assert skipped["pairs"] == 0 and skipped["consistent_px"] is None
