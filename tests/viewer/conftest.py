"""A short trained run of the tiny test clip (with held-out views), shared by the viewer tests, and
a free TCP port on the loopback interface."""

from __future__ import annotations

import socket

import pytest

# the cut of conftest.py's short_training fixture (a session fixture cannot use a function one)
SHORT = {
    "stage1.iterations": 12,
    "stage2.iterations": 12,
    "camera_init.ba_steps": 20,
    "tonemap.pretrain_steps": 10,
    "v2w.scale_refit_steps": 5,
}


@pytest.fixture(scope="session")
def viewer_run(tiny_clip_oracle, tmp_path_factory):
    """A finished run folder (renders written by the trainer) of tiny-flag-arm."""
    from m4dgs.training.pipeline import train

    out = tmp_path_factory.mktemp("viewer") / "run"
    return train(tiny_clip_oracle, out, preset="tiny", overrides=SHORT, progress=False)


@pytest.fixture(scope="session")
def viewer_model(viewer_run):
    from m4dgs.model.trained import load_model

    return load_model(viewer_run, device="cpu")


@pytest.fixture
def free_port():
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
