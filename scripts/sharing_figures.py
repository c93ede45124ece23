"""The figures of docs/results/sharing.md's web and SPZ tables, for baked scenes:

    PYTHONPATH=src python scripts/sharing_figures.py OUT LABEL=BAKED_FOLDER ...

Per scene: `export --format web`, served from 127.0.0.1 and opened in headless Chromium (SwiftShader)
at 1280 x 720, three test views (the first, the middle, the last, each at its time) against
`liquidgs render` of the baked scene at the same camera fitted to the window; then `export --format
spz` at those times, decoded by @spz-loader/core (tests/spz_reader, installed by
scripts/setup_npm_tests.sh), what it decoded rendered by liquidgs at the test camera against the
baked scene's render. It reuses the browser tests' helpers (tests/). Writes OUT/LABEL/ (the exports
and the screenshots beside liquidgs' pictures) and OUT/figures.json; prints a line per scene."""

from __future__ import annotations

import functools
import http.server
import json
import shutil
import sys
import threading
from pathlib import Path

import numpy as np
import torch
from PIL import Image

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from browser import launched_chromium  # noqa: E402
from liquidgs.cli import main as cli  # noqa: E402
from liquidgs.eval.metrics import psnr  # noqa: E402
from liquidgs.media import to_uint8  # noqa: E402
from liquidgs.train.run import load_run  # noqa: E402
from test_bake_web import WEBGL_FLAGS, QuietHandler, canvas_pixels, fitted, image_psnr, opened_page  # noqa: E402
from test_spz import SPZ_READER, decoded_render  # noqa: E402

WINDOW = {"width": 1280, "height": 720}


def served(folder: Path) -> tuple[http.server.ThreadingHTTPServer, str]:
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(QuietHandler, directory=str(folder)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, f"http://127.0.0.1:{server.server_address[1]}"


def web_figures(browser, run, frames, picks, background, web: Path, work: Path) -> dict:
    server, url = served(web)
    page, problems, requests = opened_page(browser, url, viewport=WINDOW)
    scores = []
    for index in picks:
        frame = frames[index]
        page.evaluate(f"player.show({index}, {frame.time})")
        shot = canvas_pixels(page)
        expected = to_uint8(run.render(fitted(frame.camera, **WINDOW), frame.time, background).rgb)
        Image.fromarray(np.concatenate([shot, expected], axis=0)).save(work / f"web_{index}.png")
        scores.append(round(image_psnr(shot, expected), 1))
    timing = page.evaluate("player.benchmark(5)")
    page.close()
    server.shutdown()
    outside = [r for r in requests if not r.startswith(url)]
    return {"web_psnr": scores, "web_frame_ms": timing, "web_console_errors": problems, "web_outside_requests": outside}


def spz_figures(browser, run, frames, picks, background, spz: Path) -> dict:
    (spz / "index.html").symlink_to(SPZ_READER / "index.html")
    (spz / "node_modules").symlink_to(SPZ_READER / "node_modules")
    server, url = served(spz)
    page = browser.new_page()
    page.goto(f"{url}/index.html")
    page.wait_for_selector("body[data-ready=true]", state="attached", timeout=60_000)
    scores, sizes = [], []
    for index in picks:
        frame = frames[index]
        name = f"time_{round(float(frame.time), 4):.4f}.spz"
        got = page.evaluate("(name) => decode(name)", name)
        expected = run.render(frame.camera, frame.time, background).rgb.clamp(0, 1)
        shown = decoded_render(got, run.sh_degree, frame.camera, background).clamp(0, 1)
        scores.append(round(float(psnr(shown, expected)), 1))
        sizes.append((spz / name).stat().st_size)
    page.close()
    server.shutdown()
    return {"spz_psnr": scores, "spz_bytes": sizes}


def main(out: Path, scenes: list[str]) -> None:
    torch.set_num_threads(1)
    results = {}
    chromium = launched_chromium(WEBGL_FLAGS)
    browser = next(chromium)
    for label, folder in (scene.split("=", 1) for scene in scenes):
        work = out / label
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir(parents=True)
        run = load_run(Path(folder), "cpu")
        dataset = run.scene()
        frames, background = [*dataset.test, *dataset.train], torch.tensor(dataset.background)
        picks = [0, len(dataset.test) // 2, len(dataset.test) - 1]
        times = sorted({str(round(float(frames[i].time), 4)) for i in picks})
        assert cli(["export", "--run", folder, "--format", "web", "--out", str(work)]) == 0
        assert cli(["export", "--run", folder, "--format", "spz", "--time", *times, "--out", str(work / "spz")]) == 0
        n = int(run.params["opacities"].shape[0])
        record = {"gaussians": n, "scene_bin_bytes": (work / "web" / "scene.bin").stat().st_size}
        record |= web_figures(browser, run, frames, picks, background, work / "web", work)
        record |= spz_figures(browser, run, frames, picks, background, work / "spz")
        record["spz_bytes_per_gaussian"] = round(sum(record["spz_bytes"]) / len(record["spz_bytes"]) / n, 1)
        results[label] = record
        print(label, json.dumps(record), flush=True)
    chromium.close()
    (out / "figures.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2:])
