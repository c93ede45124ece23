"""The exported .splatv's motion as a player not written here shows it: gsplat.js (npm `gsplat`
1.2.9, MIT; tests/splatv_player, installed by scripts/setup_npm_tests.sh) in headless Chromium
plays a file fitted to a known motion, a sheet of Gaussians swinging through two periods, and its
picture at mid times is compared with liquidgs' render of the motion itself (the "field"), not of
the file. One cubic per Gaussian (the export before temporal pieces) cannot hold the swing."""

from __future__ import annotations

import functools
import http.server
import math
import threading

import numpy as np
import pytest
import torch

from liquidgs.bake.formats import splatv_bytes, splatv_camera
from liquidgs.bake.pieces import fit_splatv
from liquidgs.cameras import Camera, look_at
from liquidgs.media import to_uint8
from liquidgs.render.rasterize import rasterize
from liquidgs.sh import SH_C0
from liquidgs.train.model import Deformed
from shared_data import require_installed
from test_bake_web import GSPLAT_JS, SPLATV_PLAYER, QuietHandler, browser, gsplat_js_shots, image_psnr  # noqa: F401

PIXELS = 160
TIMES = (0.3, 0.5, 0.62)
SIDES = (-0.3, 0.0, 0.3)
PIECES_DB = 30.0
"""gsplat.js' picture of the file against liquidgs' render of the swing itself. Measured 34.2-34.8
dB with temporal pieces (9 per Gaussian; what is left is mostly the pieces' overlap, bake/pieces.py
WINDOW, then float16, gsplat.js' 2.83-sigma cut-off and 8-bit blending); the same sheet exported
with one cubic per Gaussian, as the export was before pieces, scores 15.1-17.2 dB."""


class SwingingSheet:
    """A 12 x 12 sheet of opaque coloured Gaussians, each row swinging sideways through two periods
    with its own phase: a run's interface as fit_splatv reads it."""

    def __init__(self):
        rows, cols = torch.meshgrid(torch.linspace(-0.6, 0.6, 12), torch.linspace(-0.6, 0.6, 12), indexing="ij")
        self.rest = torch.stack([cols.flatten(), rows.flatten(), torch.zeros(144)], dim=1)
        self.phase = rows.flatten() * 3.0
        n = self.rest.shape[0]
        colours = torch.rand(n, 3, generator=torch.Generator().manual_seed(0)) * 0.8 + 0.1
        self.sh_degree = 0
        self.params = {
            "opacities": torch.full((n,), 4.0),
            "sh0": ((colours - 0.5) / SH_C0)[:, None, :],
            "shN": torch.zeros(n, 0, 3),
        }

    def at_time(self, time: float) -> Deformed:
        means = self.rest.clone()
        means[:, 0] += 0.25 * torch.sin(4 * math.pi * time + self.phase)
        n = means.shape[0]
        quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).expand(n, 4)
        colors = self.params["sh0"]
        return Deformed(means, quats, torch.full((n, 3), 0.05), torch.sigmoid(self.params["opacities"]), colors)


def camera(side: float = 0.0) -> Camera:
    """A view of the sheet from in front, moved `side` sideways: gsplat.js sorts again only when
    the view changes, so each time is shown from a view of its own."""
    view = look_at(torch.tensor([side, 0.0, -3.0]), torch.zeros(3), torch.tensor([0.0, -1.0, 0.0]))
    return Camera.from_fov(view, math.radians(40), PIXELS, PIXELS)


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The page, gsplat.js and the sheet's file fitted with temporal pieces and with one cubic."""
    require_installed(GSPLAT_JS, f"no gsplat.js at {GSPLAT_JS}: scripts/setup_npm_tests.sh installs it (needs npm)")
    root = tmp_path_factory.mktemp("splatv_motion")
    (root / "index.html").symlink_to(SPLATV_PLAYER / "index.html")
    (root / "node_modules").symlink_to(SPLATV_PLAYER / "node_modules")
    sheet, cameras = SwingingSheet(), [camera()]
    for name, most in (("pieces", 9), ("one_cubic", 1)):
        fitted = fit_splatv(sheet, cameras, most=most)
        (root / f"{name}.splatv").write_bytes(splatv_bytes(fitted.model, [splatv_camera(cameras[0], "front")]))
    handler = functools.partial(QuietHandler, directory=str(root))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()


@pytest.mark.slow  # Chromium, as the viewer's browser test
def test_gsplat_js_shows_the_swing_at_mid_times(browser, site):  # noqa: F811 - the browser fixture
    sheet, cameras = SwingingSheet(), [camera(side) for side in SIDES]
    views = [(splatv_camera(view, "front"), time) for view, time in zip(cameras, TIMES)]
    black = torch.zeros(3)
    scores = {}
    for name in ("pieces", "one_cubic"):
        shots, _, problems, _ = gsplat_js_shots(browser, site, f"{name}.splatv", views, [0, 0, 0], True)
        assert not problems, problems
        scores[name] = []
        for shot, view, time in zip(shots, cameras, TIMES):
            g = sheet.at_time(time)
            expected = to_uint8(
                rasterize(g.means, g.quats, g.scales, g.opacities, g.colors, view.viewmat, view.K, view.width,
                          view.height, sh_degree=0, background=black, eps2d=0.0).rgb
            )  # fmt: skip
            assert image_psnr(expected, np.zeros_like(expected)) < 20.0  # the sheet fills the picture
            scores[name].append(image_psnr(shot, expected))
    assert min(scores["pieces"]) >= PIECES_DB, scores
    assert max(scores["one_cubic"]) < PIECES_DB, scores  # the check tells the two exports apart
