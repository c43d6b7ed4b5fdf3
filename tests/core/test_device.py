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
