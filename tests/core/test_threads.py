"""m4dgs.core.threads: how a CPU budget is spent, and that the compiled kernels use the kernel
count (the forward pass is bit-identical for any count, the backward equal up to the order of the
per-thread partial sums)."""

import pytest
import torch

from m4dgs.core import threads as th


@pytest.fixture(autouse=True)
def _restore():
    before = (torch.get_num_threads(), th._kernel_threads)
    yield
    torch.set_num_threads(before[0])
    th.set_kernel_threads(before[1])


def test_a_budget_is_torch_one_kernels_all():
    assert th.use_threads(3) == (1, 3)
    assert (torch.get_num_threads(), th.kernel_threads()) == (1, 3)
    assert th.use_threads() == (1, th.cpu_budget())
    th.set_kernel_threads(None)  # unset: the kernels follow torch
    torch.set_num_threads(2)
    assert th.kernel_threads() == 2
    for bad in (0, -1):
        with pytest.raises(ValueError):
            th.use_threads(bad)
        with pytest.raises(ValueError):
            th.set_kernel_threads(bad)


def test_on_a_cuda_device_torch_gets_the_whole_budget():
    # the compiled CPU kernels are idle when gsplat rasterizes on the GPU
    assert th.use_threads(3, "cpu") == (1, 3)
    assert th.use_threads(3, "cuda") == (3, 3) and torch.get_num_threads() == 3
    assert th.use_threads(3, torch.device("cuda", 0)) == (3, 3)
    want = 3 if torch.cuda.is_available() else 1
    assert th.use_threads(3, "auto") == (want, 3)
    with th.threads_for(2, "cuda") as got:
        assert got == (2, 2)


def test_threads_for_restores_what_was_set():
    torch.set_num_threads(2)
    th.set_kernel_threads(None)
    with th.threads_for(4) as got:
        assert got == (1, 4) and (torch.get_num_threads(), th.kernel_threads()) == (1, 4)
    assert torch.get_num_threads() == 2 and th._kernel_threads is None
    with pytest.raises(RuntimeError):
        with th.threads_for(3):
            raise RuntimeError("a failed job")
    assert torch.get_num_threads() == 2 and th._kernel_threads is None


def test_the_rasterizer_uses_the_kernel_threads(monkeypatch):
    from m4dgs.raster import cpu_available, render
    from m4dgs.raster import cpu_backend as cb

    if not cpu_available():
        pytest.skip("the C++ rasterizer does not build here")
    seen = []
    ext = cb.load_extension()

    class Spy:
        def __getattr__(self, name):
            fn = getattr(ext, name)
            if name not in ("forward", "backward", "project_forward", "project_backward"):
                return fn

            def call(*args):
                seen.append((name, args[11] if name.startswith("project") else args[9]))
                return fn(*args)

            return call

    monkeypatch.setattr(cb, "load_extension", lambda: Spy())
    g = torch.Generator().manual_seed(3)
    n, W, H = 3000, 64, 48
    z = torch.rand(n, generator=g) * 3 + 2
    xy = (torch.rand(n, 2, generator=g) - 0.5) * torch.tensor([W, H]) / (0.8 * W) * z[:, None]
    base = [
        torch.cat([xy, z[:, None]], 1),
        torch.randn(n, 4, generator=g),
        torch.full((n, 3), 0.02) * z[:, None],
        torch.rand(n, generator=g) * 0.9 + 0.05,
        torch.rand(n, 5, generator=g),
    ]
    K = torch.tensor([[0.8 * W, 0.0, W / 2], [0.0, 0.8 * W, H / 2], [0.0, 0.0, 1.0]])

    def run(kernels):
        th.set_kernel_threads(kernels)
        p = [t.clone().requires_grad_(True) for t in base]
        out = render(*p, torch.eye(4), K, W, H, backend="cpu")
        (out.features.square().sum() + out.alpha.sum()).backward()
        return out.features.detach(), [q.grad for q in p]

    torch.set_num_threads(1)
    seen.clear()
    f1, g1 = run(1)
    assert {c for _, c in seen} == {1} and len(seen) == 4
    seen.clear()
    f2, g2 = run(2)
    assert {c for _, c in seen} == {2} and len(seen) == 4  # not torch's count (1)
    assert torch.equal(f1, f2)  # each tile is composited by one thread: same bits
    for a, b in zip(g1, g2):
        assert torch.allclose(a, b, rtol=1e-5, atol=1e-6)


def _threads_in_worker():
    return torch.get_num_threads(), th.kernel_threads()


def test_run_workers_spawn_for_cuda_and_set_their_threads():
    """`m4dgs-eval run --jobs N` on CUDA starts its workers with spawn (a forked child cannot use
    CUDA after its parent did); the worker initialiser survives spawn (picklable, module-level) and
    spends its budget as use_threads does."""
    from concurrent.futures import ProcessPoolExecutor

    from m4dgs.core.executors import _worker_init, pool_context

    assert pool_context("cuda").get_start_method() == "spawn"
    assert pool_context("cuda:0").get_start_method() == "spawn"
    assert pool_context("cpu").get_start_method() != "spawn"  # the platform default (fork)
    with ProcessPoolExecutor(
        1, mp_context=pool_context("cuda"), initializer=_worker_init, initargs=(2, "cpu")
    ) as ex:
        assert ex.submit(_threads_in_worker).result(timeout=120) == (1, 2)
