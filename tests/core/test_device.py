"""m4dgs.core.device: device resolution and peak memory."""

from __future__ import annotations

import pytest
import torch

from m4dgs.core import device as dv


def test_resolve_device():
    assert dv.resolve_device("cpu") == torch.device("cpu")
    assert dv.resolve_device(torch.device("cpu")) == torch.device("cpu")
    want = "cuda" if torch.cuda.is_available() else "cpu"
    assert dv.resolve_device("auto").type == want
    assert dv.resolve_device().type == want
    assert dv.resolve_device("cuda:1") == torch.device("cuda", 1)  # no availability check
    with pytest.raises(RuntimeError):
        dv.resolve_device("no-such-device")


def test_cpu_helpers_are_no_ops_and_peak_is_rss():
    assert not dv.is_cuda(None) and not dv.is_cuda("cpu")
    dv.synchronize("cpu")
    dv.reset_peak_memory(None)
    mem = dv.peak_memory_mib(torch.device("cpu"))
    assert mem is None or 1.0 < mem < 1e7  # MiB of this process's max RSS
    assert dv.peak_memory_mib(None) == pytest.approx(mem, rel=0.5)


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_peak_memory_window():
    dev = dv.resolve_device("auto")
    dv.reset_peak_memory(dev)
    x = torch.empty(64 * 2**20, dtype=torch.uint8, device=dev)  # 64 MiB
    dv.synchronize(dev)
    assert dv.peak_memory_mib(dev) >= 64
    del x


# --------------------------------------------------------------------------------------------------
# device placement: what broke on the first CUDA run (the CPU tests cannot see a second device, so
# the "meta" device stands in for it where it can)
# --------------------------------------------------------------------------------------------------
def test_camera_rig_parameters_follow_the_poses_device():
    from m4dgs.training.stage2 import CameraRig

    rig = CameraRig(torch.eye(3, device="meta"), torch.empty(4, 4, 4, device="meta"))
    assert rig.dw.device.type == rig.dt.device.type == "meta"
    assert rig.c2w().device.type == "meta"  # composing them with the poses does not cross devices


def _strategy_with_state():
    from m4dgs.training.densify import DensifyConfig, GaussianLayout, Strategy

    strat = Strategy(DensifyConfig(), GaussianLayout(), seed=3)
    strat._generator(torch.device("cpu"))  # noqa: SLF001 (created on first split, as in training)
    return strat, Strategy(DensifyConfig(), GaussianLayout(), seed=99)


def test_strategy_generator_state_loads_whatever_tensor_it_arrives_as():
    # torch.load(map_location=...) can hand the state back as a tensor other than a CPU byte tensor
    strat, fresh = _strategy_with_state()
    sd = strat.state_dict()
    want = torch.rand(5, generator=strat._generator(torch.device("cpu")))  # noqa: SLF001
    sd["generators"] = {d: s.to(torch.int64) for d, s in sd["generators"].items()}
    fresh.load_state_dict(sd)
    got = torch.rand(5, generator=fresh._generator(torch.device("cpu")))  # noqa: SLF001
    assert torch.equal(got, want)


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_strategy_state_survives_a_checkpoint_loaded_onto_the_gpu(tmp_path):
    strat, fresh = _strategy_with_state()
    want = torch.rand(5, generator=strat._generator(torch.device("cpu")))  # noqa: SLF001
    strat, fresh = _strategy_with_state()
    torch.save(strat.state_dict(), tmp_path / "s.pt")
    fresh.load_state_dict(torch.load(tmp_path / "s.pt", map_location="cuda"))
    got = torch.rand(5, generator=fresh._generator(torch.device("cpu")))  # noqa: SLF001
    assert torch.equal(got, want)
