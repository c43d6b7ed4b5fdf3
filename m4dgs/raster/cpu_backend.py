"""The ``cpu`` backend: a compiled C++/OpenMP tile rasterizer wrapped in a torch.autograd.Function.

The extension is built on first use with ``torch.utils.cpp_extension.load`` from
``csrc/rasterize_cpu.cpp`` into ``$M4DGS_EXT_DIR`` (default ``~/.cache/m4dgs/torch_extensions``),
one sub-folder per torch/Python version and per checkout (`build_folder_name`); torch rebuilds it
when the source changes. Flags are ``-O3 -fopenmp`` (never ``-march=native``); on CPUs that torch
reports as AVX2-capable (which implies FMA) a variant named ``..._avx2`` is built with ``-mavx2
-mfma`` instead, so a shared cache never hands an AVX2 build to a CPU without it."""

from __future__ import annotations

import contextlib
import functools
import hashlib
import os
import shutil
import sys
import time
from pathlib import Path

import torch
from torch import Tensor

from m4dgs.core.host import cpu_capability
from m4dgs.core.threads import kernel_threads

from .binning import TILE_SIZE, TileBins
from .projection import (
    EPS2D,
    FAR_PLANE,
    NEAR_PLANE,
    Projection,
    _check_camera,
    footprint_radii,
    tile_grid,
)

try:  # POSIX only: the build lock (build_lock)
    import fcntl
except ImportError:  # pragma: no cover
    fcntl = None

SOURCE = Path(__file__).resolve().parent / "csrc" / "rasterize_cpu.cpp"
EXT_NAME = "m4dgs_rasterize_cpu"


def _isa_flags() -> tuple[str, list[str]]:
    """(name suffix, extra compiler flags) for this CPU: AVX2 + FMA where torch detects AVX2 (or
    AVX512)."""
    if cpu_capability() in ("AVX2", "AVX512"):
        return "_avx2", ["-mavx2", "-mfma"]
    return "", []


def extension_dir() -> Path:
    """Build cache folder: ``$M4DGS_EXT_DIR`` or ``~/.cache/m4dgs/torch_extensions``, per
    torch/Python version."""
    base = os.environ.get("M4DGS_EXT_DIR") or os.path.join(
        os.path.expanduser("~"), ".cache", "m4dgs", "torch_extensions"
    )
    py = f"{sys.version_info.major}{sys.version_info.minor}"
    tag = f"torch{torch.__version__.replace('+', '_')}_py{py}"
    return Path(base) / tag


def build_folder_name(suffix: str = "") -> str:
    """The build folder of this checkout's extension: the module name plus a short hash of the
    source file's path. torch rebuilds an extension whose sources (paths included) differ from the
    last build in its folder, so two checkouts sharing one folder would rebuild it in turn (about a
    minute each time, on every first render of a process); one folder per checkout builds once."""
    tag = hashlib.sha1(str(SOURCE).encode()).hexdigest()[:8]
    return f"{EXT_NAME}{suffix}-{tag}"


@contextlib.contextmanager
def build_lock(build_dir: Path, wait_message: str = ""):
    """Hold an exclusive OS lock on ``build_dir/m4dgs.flock`` for the body (blocking; `wait_message`
    printed to stderr first when another process holds it), and delete a stale ``build_dir/lock``.

    torch marks a build in progress with a plain ``lock`` file that only the builder deletes, and
    every other process waits for it to go; a builder killed mid-compile (Ctrl-C, a job's time
    limit) leaves it behind, and every later first use would then wait forever without a word.
    The flock is released by the kernel when its holder dies, and every m4dgs process takes it
    before torch's build, so while it is held a ``lock`` file can only be a dead builder's.
    Without ``fcntl`` (not POSIX) the body runs unlocked, as before."""
    build_dir.mkdir(parents=True, exist_ok=True)
    if fcntl is None:
        yield
        return
    with open(build_dir / "m4dgs.flock", "a") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if wait_message:
                print(wait_message, file=sys.stderr, flush=True)
            fcntl.flock(fh, fcntl.LOCK_EX)
        stale = build_dir / "lock"
        if stale.exists():
            print(
                f"[m4dgs] removing {stale}: left by a build that was interrupted",
                file=sys.stderr,
                flush=True,
            )
            stale.unlink(missing_ok=True)
        yield  # closing the file releases the flock


@functools.lru_cache(maxsize=None)
def _load() -> tuple[object | None, str]:
    """(module, "") on success, (None, reason) on failure; cached so a failed build is not
    retried."""
    cxx = (
        os.environ.get("CXX")
        or shutil.which("c++")
        or shutil.which("g++")
        or shutil.which("clang++")
    )
    if cxx is None:
        return None, "no C++ compiler found (install g++ or set CXX)"
    try:
        # deferred: cpp_extension pulls in setuptools and the build machinery, only to compile
        from torch.utils import cpp_extension

        suffix, isa = _isa_flags()
        build_dir = extension_dir() / build_folder_name(suffix)
        # the first use compiles the kernel (about a minute): say so instead of sitting silent
        first_build = not any(build_dir.glob("*.so"))
        if first_build:
            print(
                f"[m4dgs] compiling the C++ rasterizer once for this torch/Python (about a minute) "
                f"into {build_dir} ...",
                file=sys.stderr,
                flush=True,
            )
            t0 = time.perf_counter()
        waiting = (
            f"[m4dgs] waiting for another process building or loading the C++ rasterizer in "
            f"{build_dir}"
        )
        with build_lock(build_dir, waiting):
            module = cpp_extension.load(
                name=EXT_NAME + suffix,
                sources=[str(SOURCE)],
                extra_cflags=["-O3", "-fopenmp", *isa],
                extra_ldflags=["-fopenmp"],
                build_directory=str(build_dir),
                verbose=False,
            )
    except Exception as exc:  # compiler errors, missing ninja, read-only cache, ...
        return None, f"building the C++ rasterizer failed: {type(exc).__name__}: {exc}"
    if first_build:
        print(f"[m4dgs] C++ rasterizer built in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return module, ""


def load_extension():
    """The compiled extension module; raises RuntimeError with the reason when it cannot be
    built."""
    module, reason = _load()
    if module is None:
        raise RuntimeError(f"m4dgs cpu rasterizer unavailable: {reason}")
    return module


def cpu_available() -> bool:
    """True when the C++ extension is (or can be) built."""
    return _load()[0] is not None


class _RasterizeCPU(torch.autograd.Function):
    """Alpha compositing of projected Gaussians; returns (features [H, W, C], alpha [H, W, 1])."""

    @staticmethod
    def forward(
        ctx, means2d, conics, opacities, features, offsets, flat_ids, width, height, tile_size
    ):
        ext = load_extension()
        n_threads = kernel_threads()
        feat, t_final, last = ext.forward(
            means2d,
            conics,
            opacities,
            features,
            offsets,
            flat_ids,
            width,
            height,
            tile_size,
            n_threads,
        )
        ctx.save_for_backward(
            means2d, conics, opacities, features, offsets, flat_ids, t_final, last
        )
        ctx.dims = (width, height, tile_size, n_threads)
        return feat, (1.0 - t_final).unsqueeze(-1)

    @staticmethod
    def backward(ctx, v_feat, v_alpha):
        means2d, conics, opacities, features, offsets, flat_ids, t_final, last = ctx.saved_tensors
        width, height, tile_size, n_threads = ctx.dims
        if v_feat is None:
            v_feat = torch.zeros((height, width, features.shape[1]), dtype=features.dtype)
        if v_alpha is None:
            v_alpha = torch.zeros((height, width, 1), dtype=features.dtype)
        ext = load_extension()
        g = ext.backward(
            means2d,
            conics,
            opacities,
            features,
            offsets,
            flat_ids,
            width,
            height,
            tile_size,
            n_threads,
            t_final,
            last,
            v_feat.to(features.dtype).contiguous(),
            v_alpha.to(features.dtype).contiguous(),
        )
        return g[:, 0:2], g[:, 2:5], g[:, 5], g[:, 6:], None, None, None, None, None


def rasterize_cpu(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    features: Tensor,
    bins: TileBins,
    width: int,
    height: int,
) -> tuple[Tensor, Tensor]:
    """Composite Gaussians (means2d [N, 2], conics [N, 3], opacities [N], features [N, C]) over the
    tiles in ``bins``. Returns features [H, W, C] and alpha [H, W, 1] (no background).
    Differentiable w.r.t. the four float inputs."""
    dtype = means2d.dtype
    return _RasterizeCPU.apply(
        means2d.contiguous(),
        conics.to(dtype).contiguous(),
        opacities.to(dtype).contiguous(),
        features.to(dtype).contiguous(),
        bins.offsets.contiguous(),
        bins.flat_ids.contiguous(),
        int(width),
        int(height),
        int(bins.tile_size),
    )


class _ProjectCPU(torch.autograd.Function):
    """Fused EWA projection (same formulas as projection.project_gaussians, hand-written
    backward)."""

    @staticmethod
    def forward(ctx, means, quats, scales, viewmat, K, ortho, width, height):
        ext = load_extension()
        n_threads = kernel_threads()
        args = (
            means,
            quats,
            scales,
            viewmat,
            K,
            ortho,
            width,
            height,
            EPS2D,
            NEAR_PLANE,
            FAR_PLANE,
            n_threads,
        )
        means2d, conics, depths, abc = ext.project_forward(*args)
        ctx.save_for_backward(means, quats, scales, viewmat, K)
        ctx.flags = (ortho, width, height, n_threads)
        ctx.mark_non_differentiable(abc)
        return means2d, conics, depths, abc

    @staticmethod
    def backward(ctx, v_means2d, v_conics, v_depths, v_abc):
        means, quats, scales, viewmat, K = ctx.saved_tensors
        ortho, width, height, n_threads = ctx.flags
        zeros = torch.zeros_like
        v_means2d = zeros(means[:, :2]) if v_means2d is None else v_means2d.contiguous()
        v_conics = zeros(means) if v_conics is None else v_conics.contiguous()
        v_depths = zeros(means[:, 0]) if v_depths is None else v_depths.contiguous()
        ext = load_extension()
        v_means, v_quats, v_scales, v_view = ext.project_backward(
            means,
            quats,
            scales,
            viewmat,
            K,
            ortho,
            width,
            height,
            EPS2D,
            NEAR_PLANE,
            FAR_PLANE,
            n_threads,
            v_means2d,
            v_conics,
            v_depths,
        )
        return v_means, v_quats, v_scales, v_view, None, None, None, None


def project_cpu(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    viewmat: Tensor,
    K: Tensor,
    width: int,
    height: int,
    camera_model: str = "pinhole",
) -> Projection:
    """The compiled counterpart of ``projection.project_gaussians`` (CPU tensors; gradients for
    means, quats, scales and viewmat). ``means_cam`` is not computed (None); ``cov2d`` is returned
    without gradient."""
    _check_camera(viewmat, K, camera_model)
    dtype = means.dtype
    means2d, conics, depths, abc = _ProjectCPU.apply(
        means.contiguous(),
        quats.to(dtype).contiguous(),
        scales.to(dtype).contiguous(),
        viewmat.to(dtype).contiguous(),
        K.to(dtype).contiguous(),
        camera_model == "ortho",
        int(width),
        int(height),
    )
    a, b, c = abc.unbind(-1)
    radii, visible = footprint_radii(means2d, a, c, a * c - b * b, depths, opacities, width, height)
    cov2d = torch.stack([a, b, b, c], dim=-1).reshape(-1, 2, 2)
    return Projection(None, means2d, cov2d, conics, depths, radii, visible)


@torch.no_grad()
def bin_cpu(
    means2d: Tensor,
    radii: Tensor,
    depths: Tensor,
    width: int,
    height: int,
    tile_size: int = TILE_SIZE,
) -> TileBins:
    """The compiled counterpart of ``binning.bin_gaussians`` (identical output): the visible
    Gaussians are depth-sorted in torch, then counting-sorted into tiles in C++ (linear time)."""
    vis = torch.nonzero((radii > 0).all(dim=-1)).squeeze(1)
    order = vis[torch.argsort(depths.detach()[vis], stable=True)]
    offsets, flat_ids = load_extension().bin_tiles(
        means2d.detach().contiguous(),
        radii.to(torch.int32).contiguous(),
        order.contiguous(),
        int(width),
        int(height),
        int(tile_size),
    )
    tiles_x, tiles_y = tile_grid(width, height, tile_size)
    return TileBins(offsets, flat_ids, tiles_x, tiles_y, tile_size)
