"""m4dgs.core.host: what run.json and clip.json record of the machine."""

from __future__ import annotations

import json
import platform

import numpy as np
import torch

from m4dgs.core import host


def test_cpu_model_reads_proc_cpuinfo(tmp_path, monkeypatch):
    fake = tmp_path / "cpuinfo"
    fake.write_text("processor\t: 0\nvendor_id\t: X\nmodel name\t: Test CPU @ 3.0GHz\nflags\t: a\n")
    real = host.Path

    monkeypatch.setattr(host, "Path", lambda p: fake if p == "/proc/cpuinfo" else real(p))
    assert host.cpu_model() == "Test CPU @ 3.0GHz"
    # without the file: the platform module's answer
    monkeypatch.setattr(host, "Path", lambda p: tmp_path / "absent")
    assert host.cpu_model() == (platform.processor() or "")


def test_host_info_is_json_and_names_torch_dispatch():
    info = host.host_info(torch.device("cpu"))
    assert json.loads(json.dumps(info)) == info
    assert info["cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert info["torch"] == torch.__version__ and info["machine"] == platform.machine()
    assert info["python"] == platform.python_version() and info["gpu"] is None
    assert info["numpy"] == np.__version__
    assert host.host_info() == info  # no device: no GPU named
