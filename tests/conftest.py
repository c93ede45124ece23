import os
import shutil
from pathlib import Path

import pytest
import torch

from field_plugins import own_entry_points
from liquidgs.data import generate_synthetic
from liquidgs.fields import registry
from shared_data import lpips_weights_dir

# Every test sees the built-in fields and liquidgs' own entry points (hexplane), whatever the
# installed metadata lists: the entry-point table is mocked, see field_plugins.py.
registry.REGISTRY = registry.FieldRegistry(own_entry_points)


def pytest_configure(config):
    """Under pytest-xdist, each worker gets its share of the cores for torch's intra-op threads: two
    workers of two threads each on two cores spend their time waiting for each other."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers > 1:
        torch.set_num_threads(max(1, (os.cpu_count() or 1) // workers))


# The files that take longest, collected first. Under `make test` (--dist loadfile --no-loadscope-reorder)
# the workers take whole files in collection order, so the long ones start at once and the last
# minute goes to short files on both cores rather than to one long file while the other core idles
# (measured: one worker finished 18 s before the other with test_quality scheduled at 212 s).
LONGEST_FIRST = (
    "test_quality.py",  # eight trainings, about 2.5 minutes
    "test_data_video.py",
    "test_experiments.py",
    "test_bake_web.py",
    "test_data_video_failures.py",
    "test_demo.py",
    "test_train.py",  # the 10-20 s files next, so only short ones are left for the end
    "test_viewer.py",
    "test_crash_safety.py",
    "test_render_cpu.py",
    "test_motion_reg.py",
    "test_wheel.py",
    "test_provenance.py",
)


def pytest_collection_modifyitems(config, items):
    rank = {name: position for position, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: the rest keep their order


@pytest.fixture
def one_torch_thread():
    """One intra-op thread: small tensors gain nothing from more, and on a shared CPU OpenMP
    threads waiting for each other slow every op down by orders of magnitude."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture
def lpips_weights():
    """The offline LPIPS backbone weights folder from ../shared (skipped without it, failed under CI)."""
    return lpips_weights_dir()


@pytest.fixture(scope="session")
def puppet_scene(tmp_path_factory) -> Path:
    """The synthetic puppet in the D-NeRF layout (32 px, 16 frames, seed 5) as <folder>/puppet, made
    once for every test that only reads a scene; a test that changes a scene changes a copy."""
    root = tmp_path_factory.mktemp("puppet_scene")
    generated = generate_synthetic("puppet", root / "generated", size=32, frames=16, seed=5)
    shutil.move(str(generated / "dnerf"), str(root / "puppet"))
    shutil.rmtree(generated)
    return root / "puppet"


@pytest.fixture(scope="session")
def tiny_mlp_run(puppet_scene, tmp_path_factory) -> Path:
    """A finished tiny MLP run on the puppet (tiny_runs.TINY_RUN), trained once for the tests that
    only read a run (bake, its formats and its web player)."""
    from tiny_runs import run_train, tiny_flags

    out = tmp_path_factory.mktemp("tiny_mlp_run") / "run"
    run_train(["--data", str(puppet_scene), "--field", "mlp", *tiny_flags(), "--out", str(out)])
    return out


@pytest.fixture(scope="session")
def coloured_baked_run(tiny_mlp_run, tmp_path_factory) -> Path:
    """tiny_mlp_run baked and coloured (tiny_runs.coloured_bake), once, for the tests of the file
    formats and players that read it; a test that changes it changes a copy."""
    from tiny_runs import coloured_bake

    return coloured_bake(tiny_mlp_run, tmp_path_factory.mktemp("coloured") / "baked")


@pytest.fixture(scope="session")
def flow_capture(tmp_path_factory) -> Path:
    """The puppet as a capture (48 px, 16 frames, seed 2) with its optical flow and motion masks at
    1x, made once for every test that only reads it; a test that changes it changes a copy."""
    pytest.importorskip("cv2", reason="optical flow needs opencv-python-headless (the dev extra installs it)")
    from liquidgs.data.flow import compute_scene_flow

    scene = generate_synthetic("puppet", tmp_path_factory.mktemp("flow_capture") / "puppet", size=48, frames=16, seed=2)
    compute_scene_flow(scene / "nerfies", None)
    return scene / "nerfies"
