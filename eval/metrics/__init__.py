"""Evaluation metrics of the Mono4DGS-HDR benchmark (conventions in docs/metrics.md).

Every metric takes numpy arrays or torch tensors ([H, W, 3] images, or [N, H, W, 3] batches scored
per image and averaged) and returns python floats (None where a metric cannot be computed, e.g.
LPIPS without weights). `CONVENTIONS` maps a short key to the one-line convention printed under the
tables (eval.tables)."""

from . import crf, geometry, hdr, image, lpips, perf, scene_hdr, temporal
from .crf import crf_error, crf_error_bands, crf_error_shifted, observed_exposure_range
from .geometry import align_sim3, ate, depth_absrel, rpe, track_error
from .hdr import hdr_flip, hdr_psnr, hdr_ssim, hdr_tonemap_pair, mu_law, pu21_encode, pu21_psnr
from .image import (
    masked_psnr,
    masked_ssim,
    psnr,
    psnr_per_image,
    roundtrip,
    roundtrip_convention,
    ssim,
)
from .lpips import LpipsWeights, load_lpips_weights, save_lpips_weights
from .lpips import lpips as lpips_metric
from .perf import measure_fps, measure_peak_memory_mib
from .temporal import dis_flow, dis_flow_sequence, hdr_t_std, hdr_tae, hdr_tae_pairs, tonemap_8bit

CONVENTIONS: dict[str, str] = {}
for _m in (image, hdr, scene_hdr, temporal, lpips, geometry, perf, crf):
    CONVENTIONS.update(_m.CONVENTIONS)
del _m

__all__ = [
    "CONVENTIONS",
    "align_sim3",
    "ate",
    "crf",
    "crf_error",
    "crf_error_bands",
    "crf_error_shifted",
    "depth_absrel",
    "dis_flow",
    "dis_flow_sequence",
    "geometry",
    "hdr",
    "hdr_flip",
    "hdr_psnr",
    "hdr_ssim",
    "hdr_t_std",
    "hdr_tae",
    "hdr_tae_pairs",
    "hdr_tonemap_pair",
    "image",
    "load_lpips_weights",
    "lpips",
    "lpips_metric",
    "LpipsWeights",
    "masked_psnr",
    "masked_ssim",
    "measure_fps",
    "measure_peak_memory_mib",
    "mu_law",
    "observed_exposure_range",
    "perf",
    "psnr",
    "psnr_per_image",
    "pu21_encode",
    "pu21_psnr",
    "roundtrip",
    "roundtrip_convention",
    "rpe",
    "save_lpips_weights",
    "scene_hdr",
    "ssim",
    "temporal",
    "tonemap_8bit",
    "track_error",
]
