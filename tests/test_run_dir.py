"""The run folder's checkpoints (m4dgs.run.RunDir): atomic writes, the previous checkpoint kept, and
the fallback to it when the newest is unreadable."""

from __future__ import annotations

import pytest
import torch

from m4dgs.run import RunDir


def test_checkpoint_keeps_the_previous_one_and_falls_back_to_it(tmp_path):
    run = RunDir(tmp_path / "run")
    assert run.read_checkpoint() is None
    run.write_checkpoint({"step": 10, "w": torch.arange(3)})
    assert not run.prev_ckpt_path.exists()
    run.write_checkpoint({"step": 20, "w": torch.arange(4)})
    assert run.read_checkpoint()["step"] == 20
    assert torch.equal(torch.load(run.prev_ckpt_path, weights_only=False)["w"], torch.arange(3))
    # a truncated newest checkpoint (a crash of the disk, a copy cut short): the previous one
    data = run.ckpt_path.read_bytes()
    run.ckpt_path.write_bytes(data[: len(data) // 2])
    with pytest.warns(RuntimeWarning, match=r"ckpt\.pt: unreadable checkpoint"):
        ck = run.read_checkpoint()
    assert ck["step"] == 10
    # both unreadable: None (the stage restarts), each named in a warning
    run.prev_ckpt_path.write_bytes(b"not a checkpoint")
    with pytest.warns(RuntimeWarning) as caught:
        assert run.read_checkpoint() is None
    named = sorted(str(w.message).split(":")[0].rsplit("/", 1)[-1] for w in caught)
    assert named == ["ckpt.prev.pt", "ckpt.pt"]
    # no temporary files left behind by the atomic writes
    assert sorted(p.name for p in (run.root / "model").iterdir()) == ["ckpt.prev.pt", "ckpt.pt"]
