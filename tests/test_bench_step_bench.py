"""bench/step_bench.py's operation counter: what it counts, checked on functions whose operations
are known by hand."""

from __future__ import annotations

import importlib.util

import torch


def _module(path, name, source):
    path.write_text(source)
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_op_counter_counts_by_innermost_package_caller(load_bench, tmp_path):
    sb = load_bench("step_bench")
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    # inner: mul, add (2 operations) and a view; outer: sum (1) and then inner
    inner = _module(
        pkg / "inner.py", "pkg_inner", "def f(a, b):\n    return (a * b + a).view(-1)\n"
    )
    outer = _module(
        pkg / "outer.py",
        "pkg_outer",
        "def g(f, a, b):\n    s = a.sum()\n    return f(a, b), s\n",
    )
    a, b = torch.ones(2, 3), torch.full((2, 3), 2.0)
    with sb.OpCounter(package=str(pkg)) as c:
        out, s = outer.g(inner.f, a, b)
        torch.neg(a)  # outside the package: "other"
    assert torch.equal(out, torch.full((6,), 3.0)) and float(s) == 6.0
    assert dict(c.ops) == {"inner.py:f": 2, "outer.py:g": 1, "other": 1}
    assert dict(c.views) == {"inner.py:f": 1}


def test_op_counter_sees_backward_at_the_backward_call(load_bench, tmp_path):
    sb = load_bench("step_bench")
    pkg = tmp_path / "pkg2"
    pkg.mkdir()
    mod = _module(
        pkg / "train.py",
        "pkg2_train",
        "def step(x):\n    y = (x * x).sum()\n    y.backward()\n    return y\n",
    )
    x = torch.ones(4, requires_grad=True)
    with sb.OpCounter(package=str(pkg)) as c:
        mod.step(x)
    assert torch.equal(x.grad, torch.full((4,), 2.0))
    # forward mul + sum, and backward's operations (at least the gradient's multiply), all at step
    assert set(c.ops) == {"train.py:step"} and c.ops["train.py:step"] >= 3
