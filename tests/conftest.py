"""Shared fixtures: tiny clips rendered once per test session with the real generator (benchgen),
torch on one thread, the tensors of a checkpoint by path, bench scripts as modules."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def _make(tmp_path_factory, scene: str, priors: str):
    from benchgen.make import make_clip
    from benchgen.suite import builtin_scenes_dir

    out = tmp_path_factory.mktemp(f"clip-{scene}-{priors}") / scene
    return make_clip(
        builtin_scenes_dir() / f"{scene}.yaml",
        out,
        preset="tiny",
        priors=priors,
        seed=0,
        progress=False,
        # a smoke-test scene: placement is tested in test_placement.py
        allow_misplaced=True,
    )


@pytest.fixture(scope="session")
def tiny_clip_oracle(tmp_path_factory):
    """tiny-flag-arm (waving flag, articulated arm, orbiting camera) with exact priors, 72x40, 9
    frames."""
    return _make(tmp_path_factory, "tiny-flag-arm", "oracle")


@pytest.fixture(scope="session")
def tiny_clip_realistic(tmp_path_factory):
    """tiny-flag-arm with the realistic prior profile."""
    return _make(tmp_path_factory, "tiny-flag-arm", "realistic")


@pytest.fixture(scope="session")
def load_bench():
    """load_bench(name): import the script bench/<name>.py as a module (bench/ is not a package)."""
    import importlib.util
    from pathlib import Path

    def load(name: str):
        path = Path(__file__).resolve().parents[1] / "bench" / f"{name}.py"
        spec = importlib.util.spec_from_file_location(name, path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod

    return load


@pytest.fixture
def one_thread():
    """torch on one thread for the test (runs repeat bit for bit only for a fixed thread count)."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture
def checkpoint_tensors():
    """checkpoint_tensors(path): {dotted path: tensor} of every tensor of a saved model."""
    from m4dgs.run import checkpoint_tensors, load_torch

    return lambda path: checkpoint_tensors(load_torch(path))


# overrides that cut a tiny-preset training to seconds (12 + 12 iterations, short bundle adjustment,
# tone-mapper pretraining and V2W refit): for tests that need a finished run, not a good one
SHORT_TRAINING = {
    "stage1.iterations": 12,
    "stage2.iterations": 12,
    "camera_init.ba_steps": 20,
    "tonemap.pretrain_steps": 10,
    "v2w.scale_refit_steps": 5,
}


@pytest.fixture
def short_training():
    """SHORT_TRAINING, a fresh copy per test."""
    return dict(SHORT_TRAINING)


@pytest.fixture(scope="session")
def short_run_realistic(tiny_clip_realistic, tmp_path_factory):
    """A finished run folder of the realistic-prior tiny clip trained with SHORT_TRAINING, shared by
    the tests that read a run and do not change it (the bench scripts' tests)."""
    from m4dgs.training.pipeline import train

    out = tmp_path_factory.mktemp("short-run") / "run"
    return train(tiny_clip_realistic, out, preset="tiny", overrides=SHORT_TRAINING, progress=False)


@pytest.fixture(scope="module")
def ray_cluster():
    """The address of a Ray cluster of three processes on this machine, started for the test
    module (tests/ray_helpers.py, start_ray_cluster): a head and two worker nodes, one CPU each,
    127.0.0.1 only, token authentication where this Ray has it; skipped without Ray."""
    pytest.importorskip("ray")
    from ray_helpers import start_ray_cluster

    with start_ray_cluster() as address:
        yield address
