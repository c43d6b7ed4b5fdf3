"""Prior degradation: depth, tracks and flow priors computed from exact ground truth
(docs/priors.md).

The method consumes priors, never ground truth (docs/priors.md). A synthetic clip gets its
priors by passing exact geometry through a ``PriorProfile``:

* ``oracle``: the exact ground truth, bit for bit (identity degradation; depth keeps 0 for "no
  surface").
* ``realistic`` (default): what a video-depth model, a point tracker and a flow network give on
  clean video.
* ``harsh``: the same failure modes, stronger.

Every random draw comes from the ``numpy.random.Generator`` passed in; ``make_rng(seed, *keys)``
derives independent, order-free generators per prior and frame, so a clip's priors are
byte-identical for one seed.

Depth (like DepthCrafter-style video depth): the output is a *depth-like* map with an unknown global
scale and a small unknown shift in disparity (video depth models are affine-invariant in disparity):
``D' = s * exp(r_t) / (d_med / D + b) * exp(sigma * n)`` with D the (edited) true depth, d_med its
clip median, b >= 0 the disparity shift (fraction of the median disparity), r_t a smooth random walk
(per-frame scale drift), n correlated unit noise. Before that, emitter and glossy pixels are pulled
towards the local background depth, no-surface pixels are filled with a far value, and disparity is
Gaussian-blurred in a band around depth discontinuities (edge smearing). Output strictly positive
and finite (float32).

Tracks (like a point tracker): a uniform grid of query points plus extra points on dynamic regions
is chosen from the ground-truth superset; positions get per-frame jitter and a random-walk drift
anchored at the query frame (faster while the point is invisible); visibility is wrong with some
probability near ground-truth visibility changes and near depth edges; a track is lost after a
random time (visible False afterwards, the position still drifts).

Flow (like RAFT between same-exposure frames): correlated noise, a smooth low-frequency error, flow
bleeding across motion/occlusion boundaries, noise multiplied where either frame is saturated (any
channel 255) or black (all channels <= 2), everything growing with the exposure difference in EV;
``valid`` is the ground-truth visibility minus the pixels an emulated forward-backward check would
reject."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
from scipy import ndimage

from m4dgs.clip import TrackSet

#: LDR code at or above which a channel counts as saturated (any channel)
SATURATED_CODE = 255
#: LDR code at or below which a pixel counts as black (all channels)
BLACK_CODE = 2


@dataclass(frozen=True)
class PriorProfile:
    """Degradation parameters of the depth, track and flow priors (units in brackets; docs/priors.md
    has the table).

    A prior whose parameters are all at their identity values (the ``oracle`` profile) is returned
    exactly."""

    name: str = "custom"

    # ---- depth
    # ----------------------------------------------------------------------------------------------
    # [stops] |log2 global scale| ~ U(lo, hi), random sign
    depth_scale_stops: Tuple[float, float] = (0.0, 0.0)
    depth_disp_shift: float = (
        0.0  # [fraction of the clip's median disparity] shift b ~ U(0, this) added to disparity
    )
    # [ln units / frame] std of the per-frame step of the log-scale random walk
    depth_drift_sigma: float = 0.0
    # [frames] Gaussian sigma smoothing the random walk over time
    depth_drift_smooth_frames: float = 0.0
    # [px] Gaussian sigma of the disparity blur around depth edges (0: none)
    depth_edge_blur_px: float = 0.0
    # [ln depth] |log depth jump| between neighbour pixels that marks an edge
    depth_edge_threshold: float = 0.05
    depth_noise_rel: float = 0.0  # [relative] std of the multiplicative log-normal depth noise
    depth_noise_corr_px: float = (
        0.0  # [px] Gaussian sigma of the noise's spatial correlation (0: white)
    )
    # [0..1] fraction of the way from true to local background depth on emitters
    depth_emitter_pull: float = 0.0
    # [0..1] same on glossy surfaces (depth of the reflection, not the surface)
    depth_glossy_pull: float = 0.0
    # [px] window of the local background (maximum filter) for the pulls
    depth_pull_window_px: int = 31
    # [relative] per-frame pull multiplier ~ U(1 - f, 1 + f) (temporal flicker)
    depth_pull_flicker: float = 0.0
    # [x clip max depth] depth of no-surface pixels; None: keep 0 when the
    depth_sky_factor: Optional[float] = None
    #                                           depth prior is identity (oracle), else 2.0

    # ---- tracks
    # ----------------------------------------------------------------------------------------------
    # [points] grid query points (None: keep every ground-truth track)
    track_num_uniform: Optional[int] = None
    track_num_dynamic: int = 0  # [points] extra query points on dynamic regions
    track_jitter_px: float = 0.0  # [px] per-frame Gaussian std per axis
    # [px / sqrt(frame)] std per axis of the random-walk step away from the query frame
    track_drift_px: float = 0.0
    # [x] drift step multiplier while the point is reported invisible
    track_occluded_drift_mult: float = 1.0
    # [frames] half-width of the window around a ground-truth visibility change
    track_vis_window: int = 0
    track_vis_flip_prob: float = 0.0  # [probability / frame] visibility flips inside that window
    track_edge_px: float = 0.0  # [px] distance to a depth edge under which visibility may also flip
    track_edge_flip_prob: float = 0.0  # [probability / frame] visibility flips near depth edges
    track_dropout_rate: float = 0.0  # [1 / frame] hazard of losing the track after its query frame

    # ---- flow
    # ----------------------------------------------------------------------------------------------
    flow_noise_px: float = 0.0  # [px] std per axis of the base error
    flow_noise_corr_px: float = 0.0  # [px] Gaussian sigma of the base error's spatial correlation
    flow_lowfreq_px: float = 0.0  # [px] std per axis of the smooth low-frequency error field
    # [cells] control grid cells across the longer image side for that field
    flow_lowfreq_cells: int = 4
    # [x] error multiplier where either frame is saturated or black
    flow_bad_exposure_mult: float = 1.0
    # [px] half-width of the band around motion/occlusion boundaries where flow bleeds
    flow_boundary_px: float = 0.0
    # [px] flow jump between neighbours that marks a motion boundary
    flow_boundary_threshold_px: float = 1.0
    # [1 / EV] error multiplier 1 + gain * |exposure gap| (mixed-level pairs)
    flow_ev_gain: float = 0.0
    # [unitless] emulated fb check: reject |e_fwd + e_bwd| > alpha * 2|F| + beta
    flow_fb_alpha: float = 0.05
    # [px] ... (None: no check, valid = ground-truth visibility)
    flow_fb_beta: Optional[float] = None

    # -- identity tests
    # ----------------------------------------------------------------------------------------------
    @property
    def depth_is_identity(self) -> bool:
        return (
            tuple(self.depth_scale_stops) == (0.0, 0.0)
            and self.depth_disp_shift == 0
            and self.depth_drift_sigma == 0
            and self.depth_edge_blur_px == 0
            and self.depth_noise_rel == 0
            and self.depth_emitter_pull == 0
            and self.depth_glossy_pull == 0
            and self.depth_sky_factor is None
        )

    @property
    def tracks_is_identity(self) -> bool:
        return (
            self.track_num_uniform is None
            and self.track_num_dynamic == 0
            and self.track_jitter_px == 0
            and self.track_drift_px == 0
            and self.track_vis_flip_prob == 0
            and self.track_edge_flip_prob == 0
            and self.track_dropout_rate == 0
        )

    @property
    def flow_is_identity(self) -> bool:
        return (
            self.flow_noise_px == 0
            and self.flow_lowfreq_px == 0
            and self.flow_boundary_px == 0
            and self.flow_fb_beta is None
        )

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["depth_scale_stops"] = list(self.depth_scale_stops)
        return d


#: exact ground truth
ORACLE = PriorProfile(name="oracle")

#: default: a good video-depth model, point tracker and flow network on clean synthetic video
REALISTIC = PriorProfile(
    name="realistic",
    depth_scale_stops=(0.5, 2.0),
    depth_disp_shift=0.02,
    depth_drift_sigma=0.01,
    depth_drift_smooth_frames=3.0,
    depth_edge_blur_px=2.0,
    depth_edge_threshold=0.05,
    depth_noise_rel=0.02,
    depth_noise_corr_px=3.0,
    depth_emitter_pull=0.5,
    depth_glossy_pull=0.3,
    depth_pull_window_px=31,
    depth_pull_flicker=0.3,
    depth_sky_factor=2.0,
    track_num_uniform=16384,
    track_num_dynamic=16384,
    track_jitter_px=0.5,
    track_drift_px=0.1,
    track_occluded_drift_mult=3.0,
    track_vis_window=2,
    track_vis_flip_prob=0.3,
    track_edge_px=2.0,
    track_edge_flip_prob=0.05,
    track_dropout_rate=0.005,
    flow_noise_px=0.3,
    flow_noise_corr_px=2.0,
    flow_lowfreq_px=0.2,
    flow_lowfreq_cells=4,
    flow_bad_exposure_mult=5.0,
    flow_boundary_px=2.0,
    flow_boundary_threshold_px=1.0,
    flow_ev_gain=0.15,
    flow_fb_alpha=0.05,
    flow_fb_beta=1.5,
)

#: stronger failure modes of the same kind
HARSH = PriorProfile(
    name="harsh",
    depth_scale_stops=(1.0, 3.0),
    depth_disp_shift=0.08,
    depth_drift_sigma=0.03,
    depth_drift_smooth_frames=3.0,
    depth_edge_blur_px=4.0,
    depth_edge_threshold=0.05,
    depth_noise_rel=0.06,
    depth_noise_corr_px=6.0,
    depth_emitter_pull=0.9,
    depth_glossy_pull=0.7,
    depth_pull_window_px=61,
    depth_pull_flicker=0.5,
    depth_sky_factor=1.5,
    track_num_uniform=8192,
    track_num_dynamic=8192,
    track_jitter_px=1.5,
    track_drift_px=0.3,
    track_occluded_drift_mult=5.0,
    track_vis_window=4,
    track_vis_flip_prob=0.5,
    track_edge_px=4.0,
    track_edge_flip_prob=0.15,
    track_dropout_rate=0.02,
    flow_noise_px=1.0,
    flow_noise_corr_px=3.0,
    flow_lowfreq_px=0.8,
    flow_lowfreq_cells=4,
    flow_bad_exposure_mult=8.0,
    flow_boundary_px=5.0,
    flow_boundary_threshold_px=1.0,
    flow_ev_gain=0.3,
    flow_fb_alpha=0.05,
    flow_fb_beta=3.0,
)


def exact_family(base: PriorProfile, name: str, *families: str) -> PriorProfile:
    """`base` with every parameter of the given families ("depth", "track", "flow") at its oracle
    (identity) value: that prior is then exact while the others stay as degraded as in `base`, with
    the same random draws (each family has its own generator, `make_rng(seed, scene, family)`)."""
    prefixes = tuple(f + "_" for f in families)
    exact = {
        f.name: getattr(ORACLE, f.name)
        for f in dataclasses.fields(PriorProfile)
        if f.name.startswith(prefixes)
    }
    return dataclasses.replace(base, name=name, **exact)


#: controls that tell which prior a result depends on (docs/priors.md, "Partly exact profiles")
REALISTIC_EXACT_DEPTH = exact_family(REALISTIC, "realistic-exact-depth", "depth")
REALISTIC_EXACT_MOTION = exact_family(REALISTIC, "realistic-exact-motion", "track", "flow")

PROFILES: Dict[str, PriorProfile] = {
    p.name: p for p in (ORACLE, REALISTIC, HARSH, REALISTIC_EXACT_DEPTH, REALISTIC_EXACT_MOTION)
}
DEFAULT_PROFILE = "realistic"


PROFILE_FILE_SUFFIXES = (".yaml", ".yml", ".json")


def load_profile(path) -> PriorProfile:
    """A profile from a YAML or JSON file: a mapping with `name` (default: the file's stem),
    `base` (a named profile, default realistic) and any PriorProfile parameters, which replace the
    base's (e.g. `{base: realistic, depth_disp_shift: 0.08}`: realistic with harsh's disparity
    shift). Raises InputError (a ValueError) naming the file and the offending key or value."""
    from m4dgs.core.errors import InputError
    from m4dgs.core.io import read_yaml

    p = Path(path)
    try:
        d = read_yaml(p)
    except OSError as e:
        raise InputError(f"{p}: cannot read a prior profile: {e}") from None
    if not isinstance(d, dict):
        raise InputError(f"{p}: a prior profile is a mapping of parameters, got {type(d).__name__}")
    d = dict(d)
    base_name = str(d.pop("base", DEFAULT_PROFILE))
    if base_name not in PROFILES:
        raise InputError(
            f"{p}: base: unknown prior profile {base_name!r}; one of {', '.join(sorted(PROFILES))}"
        )
    name = str(d.pop("name", p.stem))
    if name in PROFILES:
        raise InputError(f"{p}: name: {name!r} is a built-in profile's name; choose another")
    fields = {f.name: f for f in dataclasses.fields(PriorProfile)}
    unknown = sorted(k for k in d if k not in fields)
    if unknown:
        raise InputError(f"{p}: unknown prior parameter(s) {unknown}; docs/priors.md lists them")
    base = PROFILES[base_name]
    values = {}
    for k, v in d.items():
        kind = str(fields[k].type)  # "float", "int", "Optional[int]", "Tuple[float, float]", ...
        if kind.startswith("Tuple"):
            if not (isinstance(v, (list, tuple)) and len(v) == 2):
                raise InputError(f"{p}: {k}: expected [low, high], got {v!r}")
            if not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
                raise InputError(f"{p}: {k}: expected two numbers, got {v!r}")
            v = tuple(float(x) for x in v)
            ok = all(math.isfinite(x) and x >= 0 for x in v) and v[0] <= v[1]
            if not ok:
                raise InputError(f"{p}: {k}: expected 0 <= low <= high, got {list(v)}")
        elif v is None and kind.startswith("Optional"):
            pass
        elif isinstance(v, bool) or not isinstance(v, (int, float)):
            raise InputError(f"{p}: {k}: expected a number, got {v!r}")
        elif not (math.isfinite(v) and v >= 0):
            raise InputError(f"{p}: {k}: expected a finite number >= 0, got {v!r}")
        elif k.endswith(("_prob", "_pull")) and v > 1:
            raise InputError(f"{p}: {k}: a probability / fraction in [0, 1], got {v!r}")
        elif "int" in kind:
            if float(v) != int(v):
                raise InputError(f"{p}: {k}: expected a whole number, got {v!r}")
            v = int(v)
        else:
            v = float(v)
        values[k] = v
    return dataclasses.replace(base, name=name, **values)


def profile_key(profile: PriorProfile) -> str:
    """What a clip's generator settings record for its profile: the name of a built-in profile,
    or name@<8 hex digits of the parameters> for one from a file (a finished clip made with other
    parameters under the same name is then not taken for this one)."""
    if PROFILES.get(profile.name) == profile:
        return profile.name
    payload = json.dumps(profile.to_dict(), sort_keys=True).encode()
    return f"{profile.name}@{hashlib.sha256(payload).hexdigest()[:8]}"


def get_profile(name: str = DEFAULT_PROFILE) -> PriorProfile:
    """A built-in profile by name, or a profile file (`load_profile`) by its path."""
    if isinstance(name, PriorProfile):
        return name
    if str(name).endswith(PROFILE_FILE_SUFFIXES):
        return load_profile(name)
    try:
        return PROFILES[str(name)]
    except KeyError:
        raise KeyError(
            f"unknown prior profile {name!r}; available: {', '.join(sorted(PROFILES))}, or a "
            "profile file (.yaml / .json)"
        ) from None


def make_rng(seed: int, *keys) -> np.random.Generator:
    """Independent generator for (seed, key...) (keys: ints or strings, hashed with crc32), e.g.
    ``make_rng(seed, "depth")`` or ``make_rng(seed, "flow", a, b)``; the same arguments give the
    same stream."""
    words = [int(seed) & 0xFFFFFFFF]
    for k in keys:
        words.append(zlib.crc32(k.encode()) if isinstance(k, str) else int(k) & 0xFFFFFFFF)
    return np.random.default_rng(np.random.SeedSequence(words))


def priors_metadata(profile: PriorProfile, seed: int) -> dict:
    """The ``priors`` entry of clip.json: profile name, seed and every parameter."""
    return {"profile": profile.name, "seed": int(seed), "params": profile.to_dict()}


# --------------------------------------------------------------------------------------------------
# Random fields
# --------------------------------------------------------------------------------------------------
def _smooth_noise(shape: Tuple[int, int], corr_px: float, rng: np.random.Generator) -> np.ndarray:
    """[H, W] Gaussian noise with Gaussian spatial correlation (sigma corr_px), rescaled to unit
    std."""
    n = rng.standard_normal(shape)
    if corr_px > 0:
        n = ndimage.gaussian_filter(n, corr_px, mode="reflect")
        sd = n.std()
        if sd > 0:
            n = n / sd
    return n


def _lowfreq_field(shape: Tuple[int, int], cells: int, rng: np.random.Generator) -> np.ndarray:
    """[H, W] smooth field: unit-std Gaussian values on a (cells + 1)-per-longer-side grid,
    cubic-spline interpolated."""
    h, w = shape
    c = max(int(cells), 1)
    gh = max(2, int(round(c * h / max(h, w))) + 1)
    gw = max(2, int(round(c * w / max(h, w))) + 1)
    grid = rng.standard_normal((gh, gw))
    # tensor-product cubic spline = (1-D interpolation matrix along y) @ grid @ (along x)^T
    wy = _spline_matrix(gh, h)
    wx = _spline_matrix(gw, w)
    return wy @ grid @ wx.T


def _spline_matrix(n: int, m: int) -> np.ndarray:
    """[m, n] matrix interpolating n control values at m evenly spaced positions spanning them
    (cubic spline)."""
    pos = np.linspace(0.0, n - 1.0, m)
    eye = np.eye(n)
    return np.stack(
        [ndimage.map_coordinates(eye[j], [pos], order=3, mode="nearest") for j in range(n)], axis=1
    )


def _depth_edges(depth: np.ndarray, threshold: float) -> np.ndarray:
    """[H, W] bool: pixels with a neighbour (4-connected) whose log depth differs by more than
    threshold."""
    ld = np.log(depth)
    e = np.zeros(depth.shape, bool)
    dx = np.abs(np.diff(ld, axis=1)) > threshold
    dy = np.abs(np.diff(ld, axis=0)) > threshold
    e[:, :-1] |= dx
    e[:, 1:] |= dx
    e[:-1, :] |= dy
    e[1:, :] |= dy
    return e


def _dilate(mask: np.ndarray, radius: float) -> np.ndarray:
    r = int(math.ceil(radius))
    if r <= 0:
        return mask.copy()
    return ndimage.maximum_filter(mask.astype(np.uint8), size=2 * r + 1, mode="nearest") > 0


# --------------------------------------------------------------------------------------------------
# Depth
# --------------------------------------------------------------------------------------------------
def degrade_depth(
    depth: np.ndarray,
    emitter_mask: Optional[np.ndarray] = None,
    glossy_mask: Optional[np.ndarray] = None,
    profile: PriorProfile = REALISTIC,
    rng: Optional[np.random.Generator] = None,
) -> np.ndarray:
    """Depth prior of the training frames, like a video-depth model.

    Args:
        depth: [T, H, W] ground-truth z-depth of the training frames (0 or non-finite = no surface).
        emitter_mask, glossy_mask: [T, H, W] bool masks of emitter / glossy surfaces (or None).
        profile: degradation parameters; rng: numpy Generator (required unless the profile is
        identity).
    Returns:
        [T, H, W] float32. Identity profile: the input values exactly. Otherwise a strictly
        positive, finite depth-like map with an unknown global scale (and small disparity shift):
        only ratios are meaningful.
    """
    d_in = np.asarray(depth)
    if d_in.ndim != 3:
        raise ValueError(f"depth: expected [T, H, W], got shape {d_in.shape}")
    if profile.depth_is_identity:
        return d_in.astype(np.float32, copy=True)
    if rng is None:
        raise ValueError("degrade_depth: a numpy Generator is required for a non-identity profile")
    T, H, W = d_in.shape
    d_all = d_in.astype(np.float64)
    surface = np.isfinite(d_all) & (d_all > 0)
    if not surface.any():
        raise ValueError("degrade_depth: no surface pixel in any frame")
    d_med = float(np.median(d_all[surface]))
    far = (profile.depth_sky_factor if profile.depth_sky_factor is not None else 2.0) * float(
        d_all[surface].max()
    )
    # clip-level draws (fixed order)
    lo, hi = profile.depth_scale_stops
    stops = rng.uniform(lo, hi) if hi > lo else float(lo)
    sign = 1.0 if rng.random() < 0.5 else -1.0
    scale = 2.0 ** (sign * stops)
    shift = rng.uniform(0.0, profile.depth_disp_shift) if profile.depth_disp_shift > 0 else 0.0
    walk = (
        np.cumsum(rng.normal(0.0, profile.depth_drift_sigma, size=T))
        if profile.depth_drift_sigma > 0
        else np.zeros(T)
    )
    if profile.depth_drift_smooth_frames > 0 and T > 1:
        walk = ndimage.gaussian_filter1d(walk, profile.depth_drift_smooth_frames, mode="nearest")
    walk = walk - walk[0]  # the global scale carries the offset of frame 0
    out = np.empty((T, H, W), np.float32)
    for t in range(T):
        d = np.where(surface[t], d_all[t], far)
        # wrong values on emitters / glossy surfaces: pulled towards the local background (local
        # maximum depth)
        pulls = []
        for mask, pull in (
            (emitter_mask, profile.depth_emitter_pull),
            (glossy_mask, profile.depth_glossy_pull),
        ):
            if mask is not None and pull > 0:
                f = profile.depth_pull_flicker
                a = (
                    float(np.clip(pull * rng.uniform(1.0 - f, 1.0 + f), 0.0, 1.0))
                    if f > 0
                    else pull
                )
                pulls.append((np.asarray(mask[t], bool), a))
        if pulls:
            bg = ndimage.maximum_filter(
                d, size=max(int(profile.depth_pull_window_px), 1), mode="nearest"
            )
            for m, a in pulls:
                d = np.where(m, (1.0 - a) * d + a * bg, d)
        disp = d_med / d  # relative disparity (1 at the median depth)
        if profile.depth_edge_blur_px > 0:
            band = _dilate(
                _depth_edges(d, profile.depth_edge_threshold), 2.0 * profile.depth_edge_blur_px
            )
            blurred = ndimage.gaussian_filter(disp, profile.depth_edge_blur_px, mode="nearest")
            disp = np.where(band, blurred, disp)
        disp = disp + shift
        noise = 0.0
        if profile.depth_noise_rel > 0:
            noise = profile.depth_noise_rel * _smooth_noise(
                (H, W), profile.depth_noise_corr_px, rng
            )
        out[t] = (scale * math.exp(walk[t]) * d_med / disp * np.exp(noise)).astype(np.float32)
    if not (np.isfinite(out).all() and (out > 0).all()):
        raise FloatingPointError("degrade_depth produced a non-positive or non-finite value")
    return out


def median_scaled_absrel(
    pred: np.ndarray, gt: np.ndarray, mask: Optional[np.ndarray] = None
) -> float:
    """AbsRel mean(|s * pred - gt| / gt) over gt > 0 (and mask) after one clip-wide median scale
    s = median(gt) / median(pred) (the band of docs/priors.md is stated in this metric)."""
    m = np.isfinite(gt) & (gt > 0)
    if mask is not None:
        m &= mask
    s = np.median(gt[m]) / np.median(pred[m])
    return float(np.mean(np.abs(s * pred[m] - gt[m]) / gt[m]))


# --------------------------------------------------------------------------------------------------
# Tracks
# --------------------------------------------------------------------------------------------------
def _query_frames(visible: np.ndarray) -> np.ndarray:
    """[N] first visible frame of each track (0 for never-visible tracks)."""
    return np.argmax(visible, axis=1)


def select_track_indices(
    gt: TrackSet, width: int, height: int, profile: PriorProfile, rng: np.random.Generator
) -> np.ndarray:
    """Indices (ascending) of the ground-truth tracks a point tracker would have queried.

    Uniform part: the image is cut into a grid of about ``track_num_uniform`` cells
    (aspect-preserving); in each cell the track whose query position (position at its first visible
    frame) is nearest the cell centre is kept. Dynamic part: ``track_num_dynamic`` further tracks
    drawn at random among the remaining dynamic ones. Never-visible tracks and tracks whose query
    position is outside the image are never chosen. ``track_num_uniform`` None keeps every track.
    """
    N = gt.tracks.shape[0]
    if profile.track_num_uniform is None:
        return np.arange(N)
    vis = np.asarray(gt.visible, bool)
    q = _query_frames(vis)
    qpos = gt.tracks[np.arange(N), q].astype(np.float64)
    ok = (
        vis.any(axis=1)
        & (qpos[:, 0] >= 0)
        & (qpos[:, 0] < width)
        & (qpos[:, 1] >= 0)
        & (qpos[:, 1] < height)
    )
    cand = np.nonzero(ok)[0]
    chosen = np.zeros(N, bool)
    nu = int(profile.track_num_uniform)
    if nu > 0 and cand.size:
        nx = max(1, int(round(math.sqrt(nu * width / height))))
        ny = max(1, int(round(nu / nx)))
        cw, ch = width / nx, height / ny
        p = qpos[cand]
        ix = np.clip((p[:, 0] // cw).astype(int), 0, nx - 1)
        iy = np.clip((p[:, 1] // ch).astype(int), 0, ny - 1)
        dist = np.hypot(p[:, 0] - (ix + 0.5) * cw, p[:, 1] - (iy + 0.5) * ch)
        cell = iy * nx + ix
        # by cell, then distance, then index (deterministic ties)
        order = np.lexsort((cand, dist, cell))
        _, first = np.unique(cell[order], return_index=True)
        chosen[cand[order[first]]] = True
    if profile.track_num_dynamic > 0 and gt.dynamic is not None:
        pool = np.nonzero(ok & np.asarray(gt.dynamic, bool) & ~chosen)[0]
        k = min(int(profile.track_num_dynamic), pool.size)
        if k > 0:
            chosen[rng.choice(pool, size=k, replace=False)] = True
    return np.nonzero(chosen)[0]


def _fill_nonfinite(tr: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Replace non-finite positions of tracks [M, T, 2] by the nearest earlier (else later) finite
    position of the same track (tracks without any finite position become 0). Returns (filled,
    finite [M, T])."""
    finite = np.isfinite(tr).all(axis=-1)
    if finite.all():
        return tr, finite
    M, T = finite.shape
    t = np.arange(T)[None, :]
    last = np.maximum.accumulate(np.where(finite, t, -1), axis=1)  # latest finite index <= t
    # earliest finite index >= t
    nxt = np.minimum.accumulate(np.where(finite, t, T)[:, ::-1], axis=1)[:, ::-1]
    src = np.where(last >= 0, last, np.where(nxt < T, nxt, 0))
    out = tr[np.arange(M)[:, None], src]
    out[~finite.any(axis=1)] = 0.0
    return out, finite


def _near_change(vis: np.ndarray, window: int) -> np.ndarray:
    """[N, T] bool: frames within `window` frames of a visibility change (change between t-1 and t
    marks the frames t - window .. t + window - 1)."""
    N, T = vis.shape
    near = np.zeros((N, T), bool)
    if window <= 0 or T < 2:
        return near
    change = np.zeros((N, T), np.int64)
    change[:, 1:] = vis[:, 1:] != vis[:, :-1]
    # counts of changes c with c - window <= t <= c + window - 1  <=>  t + 1 - window <= c <= t +
    # window cs[:, k] = sum_{c<k}
    cs = np.concatenate([np.zeros((N, 1), np.int64), np.cumsum(change, axis=1)], axis=1)
    t = np.arange(T)
    lo = np.clip(t + 1 - window, 0, T)
    hi = np.clip(t + window + 1, 0, T)
    near = (cs[:, hi] - cs[:, lo]) > 0
    return near


def degrade_tracks(
    gt: TrackSet,
    depth: Optional[np.ndarray],
    width: int,
    height: int,
    profile: PriorProfile = REALISTIC,
    rng: Optional[np.random.Generator] = None,
) -> TrackSet:
    """Track prior over the training frames, like a point tracker.

    Args:
        gt: ground-truth TrackSet over the training frames (tracks [N, T, 2], visible [N, T], frames
        [T], optional
            dynamic [N]); a superset to choose the queried points from.
        depth: [T, H, W] ground-truth z-depth of the same frames (for visibility mistakes near depth
        edges) or None. width, height: image size in pixels. profile, rng: degradation parameters
        and numpy Generator (required unless the profile is identity).
    Returns:
        TrackSet(tracks [M, T, 2] float32, visible [M, T], frames) without points3d / dynamic (a
        tracker knows neither). Identity profile: tracks and visible exactly as given.
    """
    tr_gt = np.asarray(gt.tracks)
    vis_gt = np.asarray(gt.visible, bool)
    frames = np.asarray(gt.frames, np.int64).copy()
    if profile.tracks_is_identity:
        return TrackSet(
            tracks=tr_gt.astype(np.float32, copy=True), visible=vis_gt.copy(), frames=frames
        )
    if rng is None:
        raise ValueError("degrade_tracks: a numpy Generator is required for a non-identity profile")
    idx = select_track_indices(gt, width, height, profile, rng)
    tr, finite = _fill_nonfinite(tr_gt[idx].astype(np.float64))
    vis = vis_gt[idx] & finite
    M, T = vis.shape
    if depth is not None and np.shape(depth)[0] != T:
        raise ValueError(f"degrade_tracks: depth has {np.shape(depth)[0]} frames, tracks have {T}")
    q = _query_frames(vis)
    t_idx = np.arange(T)[None, :]
    is_query = t_idx == q[:, None]
    # visibility mistakes near ground-truth visibility changes and near depth edges
    flip = np.zeros((M, T), bool)
    if profile.track_vis_flip_prob > 0 and profile.track_vis_window > 0:
        flip |= _near_change(vis, int(profile.track_vis_window)) & (
            rng.random((M, T)) < profile.track_vis_flip_prob
        )
    if depth is not None and profile.track_edge_flip_prob > 0 and profile.track_edge_px > 0:
        d = np.asarray(depth, np.float64)
        near_edge = np.zeros((M, T), bool)
        u = np.floor(tr[..., 0]).astype(np.int64)
        v = np.floor(tr[..., 1]).astype(np.int64)
        inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
        for t in range(T):
            dt_ = np.where(np.isfinite(d[t]) & (d[t] > 0), d[t], 1e6)
            dist = ndimage.distance_transform_edt(~_depth_edges(dt_, profile.depth_edge_threshold))
            ii = inside[:, t]
            near_edge[ii, t] = dist[v[ii, t], u[ii, t]] <= profile.track_edge_px
        flip |= near_edge & (rng.random((M, T)) < profile.track_edge_flip_prob)
    flip &= ~is_query  # the query point is given to the tracker
    vis_out = vis ^ flip
    # drop-outs: lost after a geometric number of frames past the query frame
    if profile.track_dropout_rate > 0:
        lost_at = q + rng.geometric(min(profile.track_dropout_rate, 1.0), size=M)
        vis_out &= t_idx < lost_at[:, None]
    # positions: jitter + random-walk drift anchored at the query frame (faster while invisible)
    jitter = (
        rng.normal(0.0, profile.track_jitter_px, size=(M, T, 2))
        if profile.track_jitter_px > 0
        else np.zeros((M, T, 2))
    )
    jitter[is_query] = 0.0
    drift = np.zeros((M, T, 2))
    if profile.track_drift_px > 0:
        step_sd = profile.track_drift_px * np.where(vis_out, 1.0, profile.track_occluded_drift_mult)
        steps = rng.normal(0.0, 1.0, size=(M, T, 2)) * step_sd[..., None]
        # cs0[:, k] = sum_{s<k}
        cs0 = np.concatenate([np.zeros((M, 1, 2)), np.cumsum(steps, axis=1)], axis=1)
        rows = np.arange(M)[:, None]
        tt = np.arange(T)[None, :]
        fwd = cs0[rows, tt + 1] - cs0[np.arange(M), q + 1][:, None]  # t >= q: sum of steps q+1..t
        bwd = cs0[np.arange(M), q][:, None] - cs0[rows, tt]  # t < q: sum of steps t..q-1
        drift = np.where((tt >= q[:, None])[..., None], fwd, bwd)
    out = (tr + jitter + drift).astype(np.float32)
    return TrackSet(tracks=out, visible=vis_out, frames=frames)


# --------------------------------------------------------------------------------------------------
# Flow
# --------------------------------------------------------------------------------------------------
def exposure_bad_mask(ldr: np.ndarray) -> np.ndarray:
    """[H, W] bool: saturated (any channel >= SATURATED_CODE) or black (all channels <=
    BLACK_CODE)."""
    a = np.asarray(ldr)
    if a.ndim == 2:
        a = a[..., None]
    mx = a.max(axis=-1)
    return (mx >= SATURATED_CODE) | (mx <= BLACK_CODE)


def _flow_boundaries(flow: np.ndarray, valid: np.ndarray, threshold: float) -> np.ndarray:
    """[H, W] bool: motion boundaries (flow jump > threshold px to a 4-neighbour) and occlusion
    boundaries (valid differs from a 4-neighbour)."""
    e = np.zeros(valid.shape, bool)
    jx = (np.linalg.norm(np.diff(flow, axis=1), axis=-1) > threshold) | (
        np.diff(valid.astype(np.int8), axis=1) != 0
    )
    jy = (np.linalg.norm(np.diff(flow, axis=0), axis=-1) > threshold) | (
        np.diff(valid.astype(np.int8), axis=0) != 0
    )
    e[:, :-1] |= jx
    e[:, 1:] |= jx
    e[:-1, :] |= jy
    e[1:, :] |= jy
    return e


def degrade_flow(
    gt_flow: np.ndarray,
    gt_valid: np.ndarray,
    ldr_a: Optional[np.ndarray],
    ldr_b: Optional[np.ndarray],
    exposure_gap_ev: float = 0.0,
    profile: PriorProfile = REALISTIC,
    rng: Optional[np.random.Generator] = None,
) -> Tuple[np.ndarray, np.ndarray]:
    """Flow prior F_{a->b} between two training frames, like a flow network run on the LDR frames.

    Error model (all per axis, px): base error sigma_n (spatially correlated) + smooth low-frequency
    error sigma_lf, both multiplied by (1 + flow_ev_gain * exposure_gap_ev); the base error is
    further multiplied by flow_bad_exposure_mult where a's pixel or its ground-truth match in b is
    saturated or black; within flow_boundary_px of a motion/occlusion boundary the flow is replaced
    by a Gaussian-blurred (bled) flow.
    valid = gt_valid minus pixels an emulated forward-backward check rejects: |e_fwd + e_bwd| >
    alpha * 2|F| + beta,
    with e_bwd an independent draw of the same error model (the backward estimate's error).

    Args:
        gt_flow: [H, W, 2] exact F_{a->b} (px); gt_valid: [H, W] bool exact visibility of a's pixels
        in b. ldr_a, ldr_b: [H, W, 3] uint8 input frames (or None: no exposure-dependent error).
        exposure_gap_ev: |log2(dt_a / dt_b)| (0 for same-level pairs).
        profile, rng: degradation parameters and numpy Generator (required unless the profile is
        identity).
    Returns:
        (flow [H, W, 2] float32, valid [H, W] bool). Identity profile: the inputs exactly.
    """
    f = np.asarray(gt_flow)
    gv = np.asarray(gt_valid, bool)
    if f.ndim != 3 or f.shape[-1] != 2 or gv.shape != f.shape[:2]:
        raise ValueError(
            f"degrade_flow: expected flow [H, W, 2] and valid [H, W], got {f.shape} and {gv.shape}"
        )
    if profile.flow_is_identity:
        return f.astype(np.float32, copy=True), gv.copy()
    if rng is None:
        raise ValueError("degrade_flow: a numpy Generator is required for a non-identity profile")
    H, W = gv.shape
    f = f.astype(np.float64)
    fin = np.isfinite(f).all(axis=-1)
    if not fin.all():  # undefined ground-truth flow: treat as zero motion, never valid
        f = np.where(fin[..., None], f, 0.0)
        gv = gv & fin
    bad = np.zeros((H, W), bool)
    if ldr_a is not None:
        bad |= exposure_bad_mask(ldr_a)
    if ldr_b is not None:
        ys, xs = np.mgrid[0:H, 0:W]
        xb = np.clip(np.floor(xs + 0.5 + f[..., 0]).astype(np.int64), 0, W - 1)
        yb = np.clip(np.floor(ys + 0.5 + f[..., 1]).astype(np.int64), 0, H - 1)
        bad |= exposure_bad_mask(ldr_b)[yb, xb]
    gain = 1.0 + profile.flow_ev_gain * abs(float(exposure_gap_ev))
    base = f
    if profile.flow_boundary_px > 0:
        band = _dilate(
            _flow_boundaries(f, gv, profile.flow_boundary_threshold_px), profile.flow_boundary_px
        )
        bled = np.stack(
            [
                ndimage.gaussian_filter(f[..., c], profile.flow_boundary_px, mode="nearest")
                for c in range(2)
            ],
            -1,
        )
        base = np.where(band[..., None], bled, f)
    mult = np.where(bad, profile.flow_bad_exposure_mult, 1.0)

    def error_field() -> np.ndarray:
        e = np.zeros((H, W, 2))
        for c in range(2):
            if profile.flow_noise_px > 0:
                e[..., c] += (
                    profile.flow_noise_px
                    * mult
                    * _smooth_noise((H, W), profile.flow_noise_corr_px, rng)
                )
            if profile.flow_lowfreq_px > 0:
                e[..., c] += profile.flow_lowfreq_px * _lowfreq_field(
                    (H, W), profile.flow_lowfreq_cells, rng
                )
        return e * gain

    e_fwd = error_field()
    flow = base + e_fwd
    valid = gv.copy()
    if profile.flow_fb_beta is not None:
        e_bwd = error_field()
        fb = np.linalg.norm(2.0 * (base - f) + e_fwd + e_bwd, axis=-1)
        valid &= (
            fb <= profile.flow_fb_alpha * 2.0 * np.linalg.norm(f, axis=-1) + profile.flow_fb_beta
        )
    return flow.astype(np.float32), valid


def flow_pairs(
    train_frames: Sequence[int],
    train_dt: Sequence[float],
    num_levels: int,
    require_same_level: bool = False,
) -> List[Tuple[int, int]]:
    """Frame pairs of the flow prior: (t, t + N_e) and (t + N_e, t) in training-frame order (global
    indices).

    With the alternating schedule these frames always share the exposure level (the paper computes
    flow only between same-level frames; the trainer supervises t' in {t +- N_e}). With random-order
    / random-values schedules the two frames may differ; they are paired anyway, as in the paper's
    schedule ablation where the flow model ran on frames of different exposure, and ``degrade_flow``
    applies the EV-gap penalty (pass the gap). With ``require_same_level`` pairs whose exposure
    times differ are dropped instead."""
    fr = [int(g) for g in train_frames]
    dts = [float(v) for v in train_dt]
    if len(fr) != len(dts):
        raise ValueError(f"flow_pairs: {len(fr)} frames but {len(dts)} exposure times")
    n = int(num_levels)
    if n < 1:
        raise ValueError(f"flow_pairs: num_levels must be >= 1, got {num_levels}")
    out: List[Tuple[int, int]] = []
    for i in range(len(fr) - n):
        j = i + n
        if require_same_level and dts[i] != dts[j]:
            continue
        out.append((fr[i], fr[j]))
        out.append((fr[j], fr[i]))
    return out
