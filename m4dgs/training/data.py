"""Training inputs of one clip as tensors: LDR frames, exposures, priors (never ground truth).

Time axis: the trainer measures time in training-frame indices 0..T-1 (the spline knots live there).
A global frame g maps to the fractional index obtained by linear interpolation over the training
frames (m4dgs.clip.frame_time), so with the default split (even g train, odd g test) the test frame
between training frames i and i + 1 sits at t = i + 0.5."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import List, Optional, Sequence, Tuple

import numpy as np
import torch

from m4dgs.clip import Clip
from m4dgs.core.errors import InputError
from m4dgs.model.gaussians import VideoInitConfig


@dataclass
class TrainingData:
    """Everything the trainer may see. Shapes: T training frames, H x W pixels, N tracks, P flow
    pairs."""

    clip_name: str
    frames: List[int]  # [T] global indices of the training frames
    width: int
    height: int
    ldr: torch.Tensor  # [T, H, W, 3] float in [0, 1]
    log2_dt: torch.Tensor  # [T] log2 exposure time of each training frame (as written on the input)
    depth: torch.Tensor  # [T, H, W] depth prior (arbitrary scale), > 0 where valid
    tracks: torch.Tensor  # [N, T, 2] pixel coordinates (centres at +0.5)
    track_vis: torch.Tensor  # [N, T] bool
    flow_pairs: List[Tuple[int, int]]  # [P] (i, j) training-frame indices of F_{i->j}
    flow: Optional[torch.Tensor]  # [P, H, W, 2] pixels, or None when the clip has no flow prior
    flow_valid: Optional[torch.Tensor]  # [P, H, W] bool
    unit_exposure_value: float  # C0 of the unit-exposure loss
    num_levels: int  # N_e: number of observed exposure levels

    @property
    def num_frames(self) -> int:
        return len(self.frames)

    def flow_index(self, i: int, j: int) -> Optional[int]:
        try:
            return self.flow_pairs.index((i, j))
        except ValueError:
            return None

    def flow_targets(self, i: int) -> List[int]:
        """Training indices j with a prior flow F_{i->j}."""
        return [b for (a, b) in self.flow_pairs if a == i]


# a frame is blank (black) / saturated (white) when more than this fraction of its pixels is
BLANK_FRACTION = 0.98
BLACK_MAX, WHITE_MIN = 2, 253  # 8-bit values, every channel


def blank_frames(ldr: np.ndarray, fraction: float = BLANK_FRACTION) -> Tuple[List[int], List[int]]:
    """Indices of the frames of ldr [T, H, W, 3] uint8 that are almost all black (every channel <=
    BLACK_MAX) and of those almost all white (every channel >= WHITE_MIN), more than `fraction` of
    their pixels."""
    black = (ldr <= BLACK_MAX).all(-1).mean(axis=(1, 2)) > fraction
    white = (ldr >= WHITE_MIN).all(-1).mean(axis=(1, 2)) > fraction
    return np.flatnonzero(black).tolist(), np.flatnonzero(white).tolist()


def check_frame_content(ldr: np.ndarray, frames: Sequence[int], folder) -> None:
    """Warn about blank or saturated training frames (they carry no signal at their exposure); raise
    InputError when every frame is, before any compute."""
    black, white = blank_frames(ldr)
    if len(black) + len(white) == 0:
        return
    what = []
    if black:
        what.append(f"black: {[frames[i] for i in black]}")
    if white:
        what.append(f"saturated: {[frames[i] for i in white]}")
    msg = (
        f"{folder}: {len(black) + len(white)} of {len(frames)} training frames are blank "
        f"(> {BLANK_FRACTION:.0%} of their pixels; {'; '.join(what)})"
    )
    if len(black) + len(white) == len(frames):
        raise InputError(
            msg + "; nothing to train on (wrong files, or a 16-bit PNG read as 8-bit?)"
        )
    warnings.warn(msg + "; they constrain the reconstruction little", RuntimeWarning, stacklevel=3)


# fewest training frames a run accepts: the velocity / acceleration terms and the temporal luminance
# regularisation need a frame and its two neighbours
MIN_TRAINING_FRAMES = 3


def check_enough_frames(
    train_dt: Sequence[float], observed: Sequence[float], where, schedule: str = "alternating"
) -> None:
    """InputError (before any compute) unless there are MIN_TRAINING_FRAMES training frames and,
    for a schedule of levels (alternating, random-order; not random-values, whose exposures lie
    between the levels, nor real footage), every observed exposure level has at least one training
    frame (the tone mapper learns each level from its frames)."""
    n = len(train_dt)
    if n < MIN_TRAINING_FRAMES:
        raise InputError(
            f"{where}: split.train has {n} training frames; training needs at least "
            f"{MIN_TRAINING_FRAMES} (a frame and its two neighbours)"
        )
    if schedule not in ("alternating", "random-order"):  # random-values, real footage
        return
    missing = [o for o in observed if not any(abs(dt - o) <= 1e-6 * max(dt, o) for dt in train_dt)]
    if missing:
        raise InputError(
            f"{where}: exposures.observed lists {missing}, which no training frame has "
            f"(train_dt {sorted(set(float(d) for d in train_dt))})"
        )


def load_training_data(
    clip: Clip, device="cpu", max_tracks: Optional[int] = None, seed: int = 0
) -> TrainingData:
    """Read a clip's training inputs into tensors on `device` (float32).

    Args:
        clip: an opened clip (ground truth, if present, is not touched).
        max_tracks: keep at most this many prior tracks (uniform random subset, seeded).
    """
    frames = clip.train_frames
    ex = clip.meta.exposures
    check_enough_frames(
        [float(d) for d in clip.train_dt], ex.observed, clip.root / "clip.json", ex.schedule
    )
    ldr8 = np.stack([clip.load_ldr(g) for g in frames])
    check_frame_content(ldr8, frames, clip.root / "input" / "ldr")
    ldr = ldr8.astype(np.float32) / 255.0
    depth = np.stack([clip.load_depth_prior(g) for g in frames]).astype(np.float32)
    ts = clip.load_tracks_prior()
    tracks, vis = ts.tracks, ts.visible
    keep = vis.sum(1) >= 2  # a track seen once carries no motion
    tracks, vis = tracks[keep], vis[keep]
    if max_tracks is not None and tracks.shape[0] > max_tracks:
        idx = np.sort(
            np.random.default_rng(seed).choice(tracks.shape[0], max_tracks, replace=False)
        )
        tracks, vis = tracks[idx], vis[idx]
    index = {g: i for i, g in enumerate(frames)}
    flow = valid = None
    pairs: List[Tuple[int, int]] = []
    if clip.has_flow_prior():
        fs = clip.load_flow_prior()
        pairs = [(index[int(a)], index[int(b)]) for a, b in fs.pairs]
        flow = torch.from_numpy(fs.flow).to(device)
        valid = torch.from_numpy(fs.valid).to(device)
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a)).to(device)  # noqa: E731
    return TrainingData(
        clip_name=clip.meta.name,
        frames=list(frames),
        width=clip.width,
        height=clip.height,
        ldr=t(ldr),
        log2_dt=t(np.log2(clip.train_dt).astype(np.float32)),
        depth=t(depth),
        tracks=t(tracks.astype(np.float32)),
        track_vis=t(vis),
        flow_pairs=pairs,
        flow=flow,
        flow_valid=valid,
        unit_exposure_value=float(clip.meta.unit_exposure_value),
        num_levels=clip.meta.num_exposure_levels,
    )


def frames_and_exposures(data: TrainingData) -> Tuple[np.ndarray, np.ndarray]:
    """The training frames as numpy [T, H, W, 3] (data.ldr, floats in [0, 1]) and their exposure
    times [T] float64: what the highlight tracker reads (m4dgs.priors.highlight_tracks)."""
    ldr = data.ldr.detach().cpu().numpy()
    return ldr, np.exp2(data.log2_dt.detach().cpu().numpy().astype(np.float64))


def _chains(data: TrainingData, init: VideoInitConfig):
    """The video's highlight chains (m4dgs.priors.highlight_tracks): (tracks [M, T, 2], visible
    [M, T], centres [C, T, 2]) as numpy, init.highlight_points tracks per chain; None when there is
    no chain."""
    from m4dgs.priors.highlight_tracks import chain_centres, highlight_tracks

    points = int(init.highlight_points)
    ht, hv = highlight_tracks(
        *frames_and_exposures(data), points=points, min_area=int(init.highlight_min_area)
    )
    if ht.shape[0] == 0:
        return None
    return ht, hv, chain_centres(ht, hv, points)


def _held_depth(data: TrainingData, centres: np.ndarray) -> TrainingData:
    """data with its depth prior held along the chains whose centres [C, T, 2] are given
    (m4dgs.priors.highlight_tracks.chain_depth)."""
    from m4dgs.priors.highlight_tracks import chain_depth

    held = chain_depth(data.depth.cpu().numpy(), centres)
    return replace(data, depth=torch.from_numpy(held).to(data.depth))


def depth_data(data: TrainingData, init: VideoInitConfig) -> TrainingData:
    """The depth prior stage 2 trains on: the clip's, or with `init.highlight_depth` (beyond the
    paper) held at each highlight chain's median around the chain (m4dgs.priors.highlight_tracks,
    step 6), as stage1_data holds it for stage 1. Returns data itself when the option is off or the
    video has no chain."""
    chains = _chains(data, init) if init.highlight_depth else None
    return data if chains is None else _held_depth(data, chains[2])


def stage1_data(data: TrainingData, init: VideoInitConfig) -> Tuple[TrainingData, torch.Tensor]:
    """The priors stage 1 trains on: the clip's, or, beyond the paper, the highlight chains'
    (m4dgs.priors.highlight_tracks). With `init.highlight_motion` (step 5) the prior tracks that
    follow a chain are dropped, the chains' tracks come after the others, and the flow prior is
    invalid around each chain; with `init.highlight_depth` (step 6) the depth prior is held at
    each chain's median around the chain. Returns (data, chain [N'] bool: the tracks that come from
    a chain)."""
    none = torch.zeros(data.tracks.shape[0], dtype=torch.bool, device=data.tracks.device)
    chains = _chains(data, init) if init.highlight_motion or init.highlight_depth else None
    if chains is None:
        return data, none
    from m4dgs.priors.highlight_tracks import chain_motion

    ht, hv, centres = chains
    if init.highlight_depth:
        data = _held_depth(data, centres)
    if not init.highlight_motion:
        return data, none
    fv = None if data.flow_valid is None else data.flow_valid.cpu().numpy()
    keep, fv = chain_motion(
        data.tracks.cpu().numpy(),
        data.track_vis.cpu().numpy(),
        centres,
        data.flow_pairs,
        fv,
    )
    dev = data.tracks.device
    k = torch.from_numpy(keep).to(dev)
    tracks = torch.cat([data.tracks[k], torch.from_numpy(ht).to(data.tracks)])
    vis = torch.cat([data.track_vis[k], torch.from_numpy(hv).to(dev)])
    chain = torch.cat([none[k], torch.ones(ht.shape[0], dtype=torch.bool, device=dev)])
    valid = None if fv is None else torch.from_numpy(fv).to(data.flow_valid.device)
    return replace(data, tracks=tracks, track_vis=vis, flow_valid=valid), chain


def init_tracks(
    data: TrainingData, init: VideoInitConfig, chain: Optional[torch.Tensor] = None
) -> Tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The tracks the video Gaussians are lifted from: data's tracks, and with
    `init.highlight_tracks` (beyond the paper) the tracks of the video's bright blobs
    (m4dgs.priors.highlight_tracks) after them, unless `init.highlight_motion` put them in data
    already. chain: [N] bool, data's tracks that come from the blobs (stage1_data). Returns
    (tracks [N', T, 2], visible [N', T], always [N'] bool: the highlight tracks, which the
    initialisation's cap keeps), on data's device."""
    tracks, vis = data.tracks, data.track_vis
    if chain is not None:
        always = chain.to(tracks.device)
    else:
        always = torch.zeros(tracks.shape[0], dtype=torch.bool, device=tracks.device)
    if not init.highlight_tracks or init.highlight_motion:
        return tracks, vis, always
    from m4dgs.priors.highlight_tracks import highlight_tracks

    ht, hv = highlight_tracks(
        *frames_and_exposures(data),
        points=int(init.highlight_points),
        min_area=int(init.highlight_min_area),
    )
    if ht.shape[0] == 0:
        return tracks, vis, always
    ht_t = torch.from_numpy(ht).to(device=tracks.device, dtype=tracks.dtype)
    hv_t = torch.from_numpy(hv).to(device=tracks.device)
    one = torch.ones(ht.shape[0], dtype=torch.bool, device=tracks.device)
    return torch.cat([tracks, ht_t]), torch.cat([vis, hv_t]), torch.cat([always, one])
