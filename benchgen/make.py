"""Make one clip (and suites of clips): render, exact ground truth, exposure, tone mapping, degraded
priors.

Pipeline of `make_clip` (each step resumable; every file write is atomic; clip.json is written last,
so a folder without clip.json is an unfinished clip and is resumed, and a finished clip is skipped
unless `force`):

1. Light selection for next-event estimation (benchgen.render.choose_emitter_sampling).
2. Ground truth (`benchgen.clip_pass.render_clip_gt`) at the scene's own emitter scale: denoised HDR
   of every frame (kept in .benchgen/hdr_unit until the clip is done), z-depth, dynamic masks,
   cameras, exact flow between consecutive training frames, point tracks over all frames; measured
   render noise and HDR-TAE floor. A clip that differs from a finished one only in what comes after
   this step (camera response, exposure schedule, priors, seed) takes that clip's render instead
   (`render_from`, same `render_key`), which is most of a clip's time; its gt/hdr then equals a
   fresh render's to float32 rounding (the unit frames are the finished clip's gt/hdr divided by its
   scale) and every other ground-truth file is the same bytes.
3. HDR scale (benchgen.placement.choose_hdr_scale): one global scale chosen from those converged
   training frames so that the exposure levels sit where a bracketing camera puts them; gt/hdr =
   scale * the unit frame (light transport is linear in the emitters, so this equals rendering with
   every emitter scaled).
4. Exposure: training exposure times from the schedule; input LDR = CRF(H dt) in 8 bits; test frames
   at every observed and novel level under gt/ldr.
5. Priors through the profile (benchgen.priors): depth (with emitter/glossy masks from pixel-centre
   ray casts), tracks (from the ground-truth tracks on the training frames), flow between training
   frames (t, t +- N_e).
6. Placement (benchgen.placement.measure_placement): what the clip achieved, recomputed from its
   PNGs, into clip.json gt.placement; a clip that misses a target is finished but `make_clip` raises
   PlacementError (unless allow_misplaced), and says so again whenever the finished clip is asked
   for.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from m4dgs.clip import (
    Clip,
    ClipMeta,
    ClipWriter,
    Exposures,
    FlowSet,
    Split,
    TrackSet,
    frame_name,
    load_trackset,
)
from m4dgs.core import io as mio
from m4dgs.core.crf import clip_crf, tonemap_ldr
from m4dgs.core.errors import InputError
from m4dgs.core.host import host_info

from .exposure import (
    ExposureSettings,
    dynamic_range_stops,
    exposure_gap_ev,
    schedule_train_dt,
    test_levels,
)
from .placement import PlacementTargets, choose_hdr_scale, measure_placement
from .priors import (
    PriorProfile,
    degrade_depth,
    degrade_flow,
    degrade_tracks,
    flow_pairs,
    get_profile,
    make_rng,
    priors_metadata,
    profile_key,
)
from .scene import load_scene

# 2: small preset 64 spp with per-clip light selection (was 256 spp, uniform) 3: ground-truth track
# queries scale with the preset (small: ~15k tracks, was ~1.3k) 4: denoised renders; HDR scale from
# the clip's own converged frames with placement targets, measured in clip.json 5: textures
# band-limited for the preset's pixel grid (and coarser patterns in the scene specs), adaptive extra
# samples where the relative variance is high 6: the denoiser runs as an exposure ladder (the
# darkest tenth of a frame was 11-19 % off a 1024-spp render with one pass; docs/rendering.md)
# 7: held-out views of every test frame (gt/views/, benchgen.views) and the camera-motion
# statistics (clip.json gt.camera_motion); the training and test frames are the same as version 6's
GENERATOR_VERSION = 7

#: the fields of a finished clip's JSON files that measure wall-clock time, by file (paths of keys):
#: the only bytes in which two makes of the same clip on one machine differ, wherever its frames
#: rendered (docs/cluster.md); timing_s_per_frame.render counts the frames render tasks made too
WALL_CLOCK_FIELDS = {
    "clip.json": (
        ("generator", "seconds"),
        ("gt", "timing_s_per_frame", "render"),
        ("gt", "timing_s_per_frame", "ray_cast"),
    ),
    ".benchgen/state.json": (
        ("gt_notes", "timing_s_per_frame", "render"),
        ("gt_notes", "timing_s_per_frame", "ray_cast"),
    ),
}

#: where the unit-scale HDR frames wait for the clip's scale (removed when the clip is finished)
UNIT_HDR_DIR = (".benchgen", "hdr_unit")
#: what step 2 writes besides the unit-scale HDR frames (copied when a finished clip's render is
#: reused)
RENDER_OUTPUTS = (
    ("gt", "depth"),
    ("gt", "masks", "dynamic"),
    ("gt", "cameras.json"),
    ("gt", "flow.npz"),
    ("gt", "tracks.npz"),
)


@dataclass(frozen=True)
class Preset:
    """Clip size of a preset: resolution, frame cap, render settings
    (benchgen.render.RENDER_PRESETS) and the density of the ground-truth track queries
    (benchgen.groundtruth.select_queries, on each of the 4 reference frames)."""

    width: int
    height: int
    max_frames: int
    render: str
    # Ground-truth tracks are what the prior profiles subsample (`realistic` asks for a 16k-cell
    # uniform grid plus 16k dynamic queries, as the paper's tracker does), so they must be at least
    # that dense for the profile to mean it. With the old 256 + 64 queries per reference frame a
    # small clip had ~1.3k tracks: stage 1 (which starts from one video Gaussian per track) never
    # reconstructed a 3-pixel lamp on conveyor-occlusion-orbit.
    track_grid: int = 256  # uniform-grid cells per reference frame
    track_dynamic: int = 64  # extra random dynamic-object pixels per reference frame


PRESETS: Dict[str, Preset] = {
    "tiny": Preset(72, 40, 17, "tiny"),  # tests: seconds per clip
    # the CPU default; a 3-px query grid: ~11k grid + 4k dynamic tracks
    "small": Preset(216, 120, 101, "small", track_grid=4096, track_dynamic=1024),
    # the paper's resolution, for a big machine: a 7-px grid (~33k grid + 16k dynamic tracks)
    "paper": Preset(864, 480, 101, "paper", track_grid=8192, track_dynamic=4096),
}


def get_preset(name: str) -> Preset:
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r} (known: {', '.join(PRESETS)})")
    return PRESETS[name]


def _material_masks(cast, state):
    """Emitter and glossy pixel masks [H, W] from a ray cast and its frame state."""
    kinds = np.array(["none"] + [m.material.kind for m in state.meshes])
    k = kinds[cast.mesh + 1]
    return k == "emitter", k == "glossy"


def _generator_settings(
    scene_path,
    preset: str,
    settings: ExposureSettings,
    profile: str,
    seed: int,
    spp: int,
    crf: str = "hdrnerf",
) -> dict:
    return {
        "tool": "benchgen",
        "version": GENERATOR_VERSION,
        "scene_spec": Path(scene_path).name,
        "preset": preset,
        "seed": int(seed),
        "spp": int(spp),
        "observed": list(settings.observed),
        "novel": list(settings.novel),
        "schedule": settings.schedule,
        "priors": profile,
        "crf": crf,
    }


def _with_crf(gen: Optional[dict]) -> Optional[dict]:
    """Generator settings recorded before the response was a clip setting were all made with
    hdrnerf."""
    return None if gen is None else {"crf": "hdrnerf", **gen}


@dataclass
class _Job:
    """What every step of make_clip needs: the scene, the clip folder and its settings, and the
    resume state (.benchgen/state.json, written after each expensive step)."""

    scene_path: Path
    scene: object  # benchgen.scene.Scene
    out: Path
    preset: Preset
    frames: List[int]
    train: List[int]
    test: List[int]
    settings: ExposureSettings
    render: object  # benchgen.render.RenderSettings (light selection resolved in step 1)
    crf: object  # a response of the clip family (m4dgs.core.crf.CLIP_CRFS)
    gen: dict
    priors: PriorProfile
    seed: int
    state: dict
    state_path: Path

    @property
    def W(self) -> int:
        return self.preset.width

    @property
    def H(self) -> int:
        return self.preset.height

    def save_state(self) -> None:
        mio.write_json(self.state_path, self.state)


def make_clip(
    scene_path,
    out_dir,
    preset: str = "small",
    settings: Optional[ExposureSettings] = None,
    priors: str = "realistic",
    seed: int = 0,
    crf: str = "hdrnerf",
    force: bool = False,
    progress: bool = True,
    max_frames: Optional[int] = None,
    spp: Optional[int] = None,
    targets: Optional[PlacementTargets] = None,
    allow_misplaced: bool = False,
    render_from: Sequence = (),
) -> Path:
    """Generate one clip folder from a scene spec; returns the clip folder. Resumes an unfinished
    clip.

    render_from: finished clip folders whose render (step 2) may be reused: the first one whose
    render key (render_key; in its resume state .benchgen/state.json and clip.json gt.render_key)
    equals this clip's gives its ground truth and HDR frames instead of a new render (clip.json
    gt.render_source names it); the others are ignored.

    targets: exposure-placement targets (default: the benchmark's,
    benchgen.placement.PlacementTargets); a clip that misses one raises PlacementError after it is
    written (also when a finished clip is found again), unless allow_misplaced (then a warning).

    spp overrides the preset's samples per pixel of the HDR renders
    (benchgen.render.RENDER_PRESETS)."""
    t_start = time.perf_counter()
    job = _prepare_job(scene_path, out_dir, preset, settings, priors, seed, crf, max_frames, spp)
    if not _start_job(job, force, allow_misplaced, render_from):
        return job.out
    train_dt = schedule_train_dt(len(job.train), job.settings, job.seed)
    meta = _clip_meta(job, train_dt)
    writer = ClipWriter(job.out, meta)
    _render_ground_truth(job, writer, progress)  # 2
    _render_views(job, writer, progress)  # 2b
    _apply_hdr_scale(job, writer, meta, train_dt, targets)  # 3
    hdr_train = _write_exposures(job, writer, train_dt)  # 4
    _write_views(job, writer, meta)  # 3b, 4b
    _write_priors(job, writer, meta, train_dt)  # 5
    _record_clip_stats(job, meta, hdr_train)
    meta.generator["seconds"] = round(time.perf_counter() - t_start, 2)
    # where it was finished (a resumed or reused render may come from another machine)
    from .render import renderer_info

    meta.generator["host"] = {**host_info(), **renderer_info()}
    _finish(job, writer, meta, targets, allow_misplaced)  # 6
    return job.out


def plan_clip(
    scene_path,
    out_dir,
    preset: str = "small",
    settings: Optional[ExposureSettings] = None,
    priors: str = "realistic",
    seed: int = 0,
    crf: str = "hdrnerf",
    force: bool = False,
    max_frames: Optional[int] = None,
    spp: Optional[int] = None,
    render_from: Sequence = (),
    frames_per_task: Optional[int] = None,
    threads: Optional[int] = None,
) -> list:
    """What make_clip does before its renders, for `benchgen make --executor ray|slurm`: the
    finished-clip check, the resume state (started over under `force` as make_clip does), a reused
    render and the light selection (step 1), kept in the resume state; returns the render tasks
    (benchgen.distribute.RenderSpec) of the frames and views still to render, [] for a finished
    clip. make_clip with the same arguments (force False) then makes the clip from their frames.

    frames_per_task: frames of one task (default benchgen.distribute.DEFAULT_FRAMES_PER_TASK);
    threads: Mitsuba's threads in each task."""
    from .distribute import DEFAULT_FRAMES_PER_TASK, clip_specs

    job = _prepare_job(scene_path, out_dir, preset, settings, priors, seed, crf, max_frames, spp)
    try:
        if not _start_job(job, force, False, render_from):
            return []
    except PlacementError:
        return []  # finished: make_clip reports the miss
    job.save_state()
    return clip_specs(
        job, job.out.joinpath(*UNIT_HDR_DIR), frames_per_task or DEFAULT_FRAMES_PER_TASK, threads
    )


def _start_job(job: _Job, force: bool, allow_misplaced: bool, render_from: Sequence) -> bool:
    """What comes before a clip's renders, in make_clip and plan_clip alike: False for a finished
    clip (_finished_clip); else the resume state opened (started over under `force`), a reused
    render taken (render_from) and the light selection chosen (step 1); True."""
    if _finished_clip(job, force, allow_misplaced):
        return False
    _open_state(job, force)
    _reuse_render(job, render_from)
    _choose_light_selection(job)  # 1
    return True


def _prepare_job(scene_path, out_dir, preset, settings, priors, seed, crf, max_frames, spp) -> _Job:
    """The scene (textures band-limited for the preset's pixel grid), frame split, render settings
    (spp override), response and generator settings of a clip."""
    from .render import RenderSettings

    settings = settings or ExposureSettings()
    pr = get_preset(preset)
    scene = load_scene(scene_path, band_limit=(pr.width, pr.height))
    G = min(scene.num_frames, pr.max_frames if max_frames is None else max_frames)
    if G < 3:
        raise ValueError(
            f"{scene_path}: a clip needs at least 3 frames, the spec gives {scene.num_frames}"
        )
    render_settings = RenderSettings.resolve(pr.render)
    if spp is not None:
        if int(spp) < 1:
            raise ValueError(f"spp must be >= 1, got {spp}")
        render_settings = dataclasses.replace(render_settings, spp=int(spp))
    # a response of the clip family (m4dgs.core.crf.CLIP_CRFS), recorded in clip.json
    crf_fn = clip_crf(crf)
    # a built-in profile or a profile file, read (and checked) before anything is rendered
    profile = get_profile(priors)
    gen = _generator_settings(
        scene_path, preset, settings, profile_key(profile), seed, render_settings.spp, crf_fn.name
    )
    frames = list(range(G))
    out = Path(out_dir)
    return _Job(
        scene_path=Path(scene_path),
        scene=scene,
        out=out,
        preset=pr,
        frames=frames,
        train=frames[0::2],
        test=frames[1::2],
        settings=settings,
        render=render_settings,
        crf=crf_fn,
        gen=gen,
        priors=profile,
        seed=int(seed),
        state={},
        state_path=out / ".benchgen" / "state.json",
    )


def _finished_clip(job: _Job, force: bool, allow_misplaced: bool) -> bool:
    """True when a finished clip with the same generator settings is there (its placement is
    checked again); raises when a finished clip with other settings is there (unless force)."""
    out = job.out
    if (out / "clip.json").exists() and not force:
        done = Clip.open(out).meta
        old = _with_crf(done.generator)
        if {k: old.get(k) for k in job.gen} == job.gen:  # finished with the same settings
            key, old_key = render_key(job), done.gt.get("render_key")
            if old_key is not None and old_key != key:  # ... but from another spec
                raise FileExistsError(
                    f"{out}: a finished clip rendered from another version of "
                    f"{job.scene_path.name} exists (render key {old_key}, now {key}); remove the "
                    "folder or pass force to make it again"
                )
            check_clip_placement(
                out, done.gt.get("placement"), allow_misplaced, job.scene_path, job.gen["preset"]
            )
            return True
        raise FileExistsError(
            f"{out}: a finished clip with other settings exists (generator {old}); pass force"
        )
    return False


def _open_state(job: _Job, force: bool) -> None:
    """Load the resume state of an unfinished clip (refusing one made with other settings)."""
    out = job.out
    if force and (out / "clip.json").exists():
        (out / "clip.json").unlink()
    state = mio.read_json(job.state_path) if job.state_path.exists() else {}
    key, old_key = render_key(job), state.get("render_key")
    same_settings = _with_crf(state.get("generator")) in (None, job.gen)
    other_render = old_key is not None and old_key != key
    if force and (other_render or not same_settings):
        # made again from scratch: nothing kept for resuming belongs to the clip asked for
        for p in list(out.iterdir()):
            shutil.rmtree(p) if p.is_dir() else p.unlink()
        state = {}
    elif other_render and same_settings:
        # the renders kept for resuming are of another version of the scene spec (its bytes):
        # resuming would finish the new clip with the old frames
        raise FileExistsError(
            f"{out}: an unfinished clip rendered from another version of {job.scene_path.name} "
            f"is here (render key {old_key}, now {key}); remove the folder or pass force to "
            "render it again, or pick another --out"
        )
    if _with_crf(state.get("generator")) not in (None, job.gen):
        raise FileExistsError(
            f"{out}: an unfinished clip with other settings is here; remove it or pick another "
            "--out"
        )
    state["generator"] = job.gen
    job.state = state


def render_key(job: _Job) -> str:
    """Fingerprint (16 hex digits) of everything steps 1 and 2 read: the generator version, the
    scene spec's bytes, the preset (resolution, frame cap, track queries), the frame count and the
    render settings as requested (light selection "auto" included: its choice is deterministic).
    Clips that differ only in the camera response, the exposures, the priors or the seed share
    it."""
    payload = {
        "version": GENERATOR_VERSION,
        "preset": dataclasses.asdict(job.preset),
        "frames": len(job.frames),
        "render": dataclasses.asdict(job.render),
    }
    h = hashlib.sha256(json.dumps(payload, sort_keys=True).encode())
    h.update(job.scene_path.read_bytes())
    return h.hexdigest()[:16]


def _reuse_render(job: _Job, candidates: Sequence) -> None:
    """Steps 1-2 from a finished clip with the same render_key, when one of `candidates` is one:
    its light selection and ground-truth notes (resume state), the files of RENDER_OUTPUTS
    (copied) and the unit-scale HDR frames (its gt/hdr divided by its hdr_scale). Nothing happens
    when step 2 is already done, no candidate matches, or the candidate is this clip."""
    state = job.state
    key = render_key(job)
    state["render_key"] = key
    if "gt_notes" in state:
        return
    for c in candidates:
        src = Path(c)
        if not (src / "clip.json").exists() or src.resolve() == job.out.resolve():
            continue
        src_state_path = src / ".benchgen" / "state.json"
        if not src_state_path.exists():
            continue
        # the key is read from the resume state (clip.json gt.render_key holds the same), which
        # is outside the clip's input fingerprint
        src_state = mio.read_json(src_state_path)
        if src_state.get("render_key") != key or "gt_notes" not in src_state:
            continue
        src_meta = Clip.open(src).meta
        for rel in RENDER_OUTPUTS:
            a, b = src.joinpath(*rel), job.out.joinpath(*rel)
            if a.is_dir():
                shutil.rmtree(b, ignore_errors=True)
                shutil.copytree(a, b)
            elif a.exists():
                b.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(a, b)
        unit_dir = job.out.joinpath(*UNIT_HDR_DIR)
        unit_dir.mkdir(parents=True, exist_ok=True)
        inv = 1.0 / float(src_meta.hdr_scale)
        for g in job.frames:
            h = mio.read_exr(src / "gt" / "hdr" / frame_name(g, "exr")).astype(np.float64)
            mio.write_exr(unit_dir / frame_name(g, "exr"), (h * inv).astype(np.float32))
        _reuse_views(src, src_state, job, inv)
        for k in ("emitter_sampling", "emitter_sampling_noise", "gt_notes", "views_notes"):
            if k in src_state:
                state[k] = src_state[k]
        # relative to this clip, so that a moved experiment root stays readable
        state["render_source"] = os.path.relpath(src.resolve(), job.out.resolve())
        job.save_state()
        return


def _reuse_views(src: Path, src_state: dict, job: _Job, inv: float) -> None:
    """The held-out views of a finished clip with the same render: their geometry files copied,
    their unit-scale HDR frames (its views' HDR divided by its scale) written for step 3b."""
    for name in src_state.get("views_notes", {}):
        a, b = src / "gt" / "views" / name, job.out / "gt" / "views" / name
        for part in ("depth", "masks", "covis"):
            shutil.rmtree(b / part, ignore_errors=True)
            shutil.copytree(a / part, b / part)
        shutil.copy2(a / "cameras.json", b / "cameras.json")
        unit = job.out.joinpath(*UNIT_HDR_DIR, "views", name)
        for g in job.test:
            h = mio.read_exr(a / "hdr" / frame_name(g, "exr")).astype(np.float64)
            mio.write_exr(unit / frame_name(g, "exr"), (h * inv).astype(np.float32))


def _choose_light_selection(job: _Job) -> None:
    """Step 1: light selection for next-event estimation (benchgen.render.choose_emitter_sampling)
    when the preset asks for "auto"; the choice is kept in the resume state."""
    from .render import choose_emitter_sampling

    if job.render.emitter_sampling != "auto":
        return
    state = job.state
    if "emitter_sampling" not in state:
        W, H = job.W, job.H
        mode, scores = choose_emitter_sampling(job.scene.frame(0, W, H), W, H, job.render)
        state["emitter_sampling"], state["emitter_sampling_noise"] = mode, scores
        job.save_state()
    job.render = dataclasses.replace(job.render, emitter_sampling=state["emitter_sampling"])


def _clip_meta(job: _Job, train_dt) -> ClipMeta:
    scene = job.scene
    return ClipMeta(
        name=scene.name,
        width=job.W,
        height=job.H,
        fps=float(scene.fps),
        frames=job.frames,
        split=Split(job.train, job.test),
        exposures=Exposures(
            train_dt=[float(v) for v in train_dt],
            observed=list(job.settings.observed),
            novel=list(job.settings.novel),
            schedule=job.settings.schedule,
        ),
        crf=job.crf.name,
        unit_exposure_value=float(job.crf(np.float64(1.0))),
        hdr_scale=1.0,
        generator=job.gen,
    )


def _render_ground_truth(job: _Job, writer: ClipWriter, progress: bool) -> None:
    """Step 2: ground truth at the scene's own (unit) emitter scale; the HDR frames go to
    .benchgen/hdr_unit until the scale is known."""
    from .clip_pass import render_clip_gt
    from .distribute import read_frame_stats

    if "gt_notes" in job.state:
        return
    job.state["gt_notes"] = render_clip_gt(
        job.scene,
        job.W,
        job.H,
        job.frames,
        job.render,
        writer,
        progress=progress,
        num_grid=job.preset.track_grid,
        num_dynamic=job.preset.track_dynamic,
        hdr_dir=UNIT_HDR_DIR,
        # frames that render tasks made (benchgen.distribute) count as rendered here
        rendered=read_frame_stats(job.out.joinpath(*UNIT_HDR_DIR), job.frames),
    )
    job.save_state()


def _render_views(job: _Job, writer: ClipWriter, progress: bool) -> None:
    """Step 2b: every held-out view (benchgen.views; the spec's camera.views) of every test frame
    at the unit emitter scale, into .benchgen/hdr_unit/views/<view>/, with its z-depth, dynamic
    mask and co-visibility mask (against every training frame) under gt/views/<view>/; the view
    cameras, their baselines and the clip's camera-motion statistics go into the resume state.
    Resumes view by view and frame by frame."""
    from .clip_pass import frame_progress
    from .groundtruth import cameras_from_states, dynamic_mask
    from .render import Renderer
    from .views import (
        baseline,
        covisibility,
        pivot_distance,
        placement_problem,
        view_c2w,
        view_seed,
        view_state,
    )

    state = job.state
    views = job.scene.spec["camera"]["views"]
    if "views_notes" in state or not views or not job.test:
        state.setdefault("views_notes", {})
        if "camera_motion" not in state:
            state["camera_motion"] = _camera_motion(job)
        return
    W, H, scene = job.W, job.H, job.scene
    caster = Renderer(scene.frame(job.train[0], W, H), W, H, job.render)
    train_states, train_casts = [], []
    for g in job.train:
        st = scene.frame(g, W, H)
        caster.update(st)
        train_states.append(st)
        train_casts.append(caster.cast_rays())
    unit = job.out.joinpath(*UNIT_HDR_DIR, "views")
    notes = {
        v["name"]: {"spec": v, "angle_deg": [], "translation": [], "covisible": []} for v in views
    }
    states = {v["name"]: [] for v in views}
    for g in frame_progress(job.test, scene, progress):
        st = scene.frame(g, W, H)
        caster.update(st)
        frame_cast = caster.cast_rays()
        dist, surface = pivot_distance(frame_cast.depth), float(frame_cast.hit.mean())
        if not np.isfinite(dist):
            raise InputError(
                f"{job.scene_path}: camera.views: test frame {g} sees no surface, so its views "
                "have no look-at point"
            )
        for i, v in enumerate(views):
            name = v["name"]
            vst = view_state(st, view_c2w(st.c2w, dist, v["orbit_deg"], v["offset"]))
            states[name].append(vst)
            caster.update(vst)
            cast = caster.cast_rays()
            problem = placement_problem(cast.depth, dist, surface)
            if problem is not None:
                raise InputError(
                    f"{job.scene_path}: camera.views[{i}] ({name}) at test frame {g}: {problem}; "
                    "choose a smaller orbit_deg or offset"
                )
            b = baseline(st.c2w, vst.c2w, dist)
            notes[name]["angle_deg"].append(b["angle_deg"])
            notes[name]["translation"].append(b["translation"])
            covis = covisibility(cast, train_states, train_casts)
            notes[name]["covisible"].append(float(covis.sum() / max(cast.hit.sum(), 1)))
            hdr_path = unit / name / frame_name(g, "exr")
            if not hdr_path.exists():
                hdr = caster.render_hdr(seed=view_seed(job.render.seed, i, g))
                mio.write_exr(hdr_path, hdr)
            writer.write_view_depth(name, g, cast.depth)
            writer.write_view_mask(name, "masks/dynamic", g, dynamic_mask(cast.instance, vst))
            writer.write_view_mask(name, "covis", g, covis)
    for name in notes:
        writer.write_view_cameras(name, cameras_from_states(states[name]))
        n = notes[name]
        n["angle_deg"] = float(np.mean(n["angle_deg"]))
        n["translation"] = float(np.mean(n["translation"]))
        n["covisible"] = float(np.mean(n["covisible"]))
    state["views_notes"] = notes
    state["camera_motion"] = _camera_motion(job)
    job.save_state()


def _camera_motion(job: _Job) -> dict:
    """clip.json gt.camera_motion (benchgen.views.camera_motion) from the ground truth on disk:
    cameras, z-depth of every frame, the tracks' 3D points."""
    from .views import camera_motion, pivot_distance

    out = job.out
    cams = mio.read_json(out / "gt" / "cameras.json")
    dist = [
        pivot_distance(mio.read_exr(out / "gt/depth" / frame_name(g, "exr"))) for g in job.frames
    ]
    tracks = load_trackset(out / "gt/tracks.npz")
    return camera_motion(
        np.asarray(cams["c2w"]),
        np.asarray(dist),
        float(job.scene.fps),
        tracks.points3d,
        tracks.dynamic,
    )


def _write_views(job: _Job, writer: ClipWriter, meta: ClipMeta) -> None:
    """Steps 3b and 4b: the views' HDR at the clip's scale, their LDR at every observed and novel
    level (as the test frames'), and their notes into clip.json gt.views and gt.camera_motion."""
    scale = np.float32(meta.hdr_scale)
    levels = test_levels(job.settings)
    unit = job.out.joinpath(*UNIT_HDR_DIR, "views")
    for name in job.state.get("views_notes", {}):
        for g in job.test:
            h = None
            if not writer.exists("gt", "views", name, "hdr", frame_name(g, "exr")):
                h = mio.read_exr(unit / name / frame_name(g, "exr")) * scale
                writer.write_view_hdr(name, g, h.astype(np.float32))
            for lv in levels:
                if writer.exists(
                    "gt", "views", name, "ldr", f"{float(lv):g}", frame_name(g, "png")
                ):
                    continue
                if h is None:
                    h = mio.read_exr(job.out / "gt" / "views" / name / "hdr" / frame_name(g, "exr"))
                writer.write_view_ldr(name, lv, g, tonemap_ldr(h, float(lv), job.crf))
    meta.gt["views"] = job.state.get("views_notes", {})
    meta.gt["views_convention"] = (
        "held-out viewpoints of every test frame (benchgen.views): the camera swung about its "
        "look-at point by orbit_deg [yaw, pitch], then moved by offset [right, up, forward] x the "
        "look-at distance; angle_deg and translation: mean baseline to the test camera; covisible: "
        "mean fraction of surface pixels seen by >= 2 training frames"
    )
    meta.gt["camera_motion"] = job.state.get("camera_motion")


def scale_key(job: _Job, train_dt, targets: PlacementTargets) -> str:
    """Fingerprint (16 hex digits) of everything step 3 reads besides the render: the render key,
    the camera response, the exposure settings, the training and test frames with their exposure
    times, and the placement targets. Clips that differ only in their priors or trainer-side
    settings share it, and so their HDR scale."""
    payload = {
        "render_key": job.state.get("render_key"),
        "crf": job.crf.metadata(),
        "exposures": dataclasses.asdict(job.settings),
        "train": [int(g) for g in job.train],
        "test": [int(g) for g in job.test],
        "train_dt": [float(x) for x in train_dt],
        "targets": dataclasses.asdict(targets),
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:16]


def _scale_source(job: _Job, key: str) -> Optional[Tuple[Path, dict]]:
    """(folder, resume state) of the clip this clip's render came from (resume state
    `render_source`) when that clip is finished and its HDR scale was chosen with the same
    scale_key; else None (clips made before scale keys existed included)."""
    rel = job.state.get("render_source")
    if rel is None:
        return None
    src = (job.out / rel).resolve()
    src_state_path = src / ".benchgen" / "state.json"
    if not (src / "clip.json").exists() or not src_state_path.exists():
        return None
    src_state = mio.read_json(src_state_path)
    if src_state.get("scale_key") != key or "hdr_scale" not in src_state:
        return None
    if not all((src / "gt" / "hdr" / frame_name(g, "exr")).exists() for g in job.frames):
        return None
    return src, src_state


def _apply_hdr_scale(job: _Job, writer: ClipWriter, meta: ClipMeta, train_dt, targets) -> None:
    """Step 3: one global HDR scale from the clip's own converged frames, then gt/hdr = scale *
    unit frame (light transport is linear in the emitters, so this equals rendering with every
    emitter scaled); the ground-truth notes go into meta.gt."""
    from .render import EMITTER_PROBE_SPP

    state, out = job.state, job.out
    targets = targets or PlacementTargets()
    if "hdr_scale" not in state:
        key = scale_key(job, train_dt, targets)
        source = _scale_source(job, key)
        if source is not None:
            # the render's source clip chose its scale from the same unit frames, response,
            # exposures and targets: take its scale and its HDR frames, so that the two clips'
            # inputs are the same bytes (the unit frames rebuilt from its gt/hdr differ from the
            # rendered ones by float32 rounding, and a scale chosen again from them moves a few
            # 8-bit codes by one)
            src, src_state = source
            (out / "gt" / "hdr").mkdir(parents=True, exist_ok=True)
            for g in job.frames:
                name = frame_name(g, "exr")
                shutil.copy2(src / "gt" / "hdr" / name, out / "gt" / "hdr" / name)
            scale, report = float(src_state["hdr_scale"]), src_state["hdr_scale_report"]
        else:
            # HDR frames without a scale in the resume state are an interrupted copy from a
            # source that is no longer eligible: they would not match the scale chosen now
            shutil.rmtree(out / "gt" / "hdr", ignore_errors=True)
            scale, report = choose_hdr_scale(
                _frames_by_level(out, job.settings, job.train, train_dt, job.test),
                job.crf,
                targets,
            )
        state["hdr_scale"], state["hdr_scale_report"] = float(scale), report
        state["scale_key"] = key
        job.save_state()
    scale = float(state["hdr_scale"])
    meta.hdr_scale = scale
    for g in job.frames:
        if not writer.exists("gt", "hdr", frame_name(g, "exr")):
            unit = mio.read_exr(out.joinpath(*UNIT_HDR_DIR, frame_name(g, "exr")))
            writer.write_gt_hdr(g, (unit * np.float32(scale)).astype(np.float32))
    meta.gt.update(state["gt_notes"])
    meta.gt["render_key"] = state.get("render_key")
    if "render_source" in state:
        meta.gt["render_source"] = state["render_source"]
    meta.gt["hdr_scale_report"] = state.get("hdr_scale_report")
    # formula, source, parameters and f(1) per channel of the response
    meta.gt["crf"] = job.crf.metadata()
    if "emitter_sampling_noise" in state:
        meta.gt["emitter_sampling_probe"] = {
            "chosen": state["emitter_sampling"],
            "spp": EMITTER_PROBE_SPP,
            "noise_tae_two_seeds": state["emitter_sampling_noise"],
        }
    meta.gt["textures"] = _texture_notes(job.scene)


def _texture_notes(scene) -> dict:
    """clip.json gt.textures: the pixel grid the textures are band-limited for and, per textured
    object, the lowest and highest cutoff (cycles per texture side) of its band limit (None: never
    in view, only the bitmap's own limit)."""
    from .textures import band_cutoffs

    objs = {
        scene.objects[i].name: None if B is None else [round(c, 3) for c in band_cutoffs(B)]
        for i, B in sorted(scene.texture_band.items())
    }
    return {
        "band_limit_grid": None if scene.band_limit is None else list(scene.band_limit),
        "cutoff_cycles_per_side": objs,
    }


def _write_exposures(job: _Job, writer: ClipWriter, train_dt) -> Dict[int, np.ndarray]:
    """Step 4: input LDR = CRF(H dt) in 8 bits for the training frames, and the test frames at
    every observed and novel level under gt/ldr; returns the training HDR frames."""
    out, crf_fn = job.out, job.crf
    hdr_train = {}
    for g, dt in zip(job.train, train_dt):
        hdr_train[g] = mio.read_exr(out / "gt/hdr" / frame_name(g, "exr"))
        if not writer.exists("input", "ldr", frame_name(g, "png")):
            writer.write_input_ldr(g, tonemap_ldr(hdr_train[g], float(dt), crf_fn))
    levels = test_levels(job.settings)
    for g in job.test:
        h = None
        for lv in levels:
            if not writer.exists("gt", "ldr", f"{float(lv):g}", frame_name(g, "png")):
                h = mio.read_exr(out / "gt/hdr" / frame_name(g, "exr")) if h is None else h
                writer.write_gt_ldr(lv, g, tonemap_ldr(h, float(lv), crf_fn))
    return hdr_train


def _write_priors(job: _Job, writer: ClipWriter, meta: ClipMeta, train_dt) -> None:
    """Step 5: degraded priors through the profile (benchgen.priors): depth (with emitter/glossy
    masks from pixel-centre ray casts), tracks (from the ground-truth tracks on the training frames)
    and flow between training frames (t, t +- N_e)."""
    from .groundtruth import flow_between
    from .render import Renderer

    out, scene, seed, train = job.out, job.scene, job.seed, job.train
    W, H = job.W, job.H
    profile = job.priors
    clip_key = scene.name
    depth_gt = np.stack([mio.read_exr(out / "gt/depth" / frame_name(g, "exr")) for g in train])
    pairs = flow_pairs(train, train_dt, len(job.settings.observed))
    need = sorted({g for p in pairs for g in p})
    caster = Renderer(scene.frame(0, W, H), W, H, dataclasses.replace(job.render, denoise=False))
    casts, states = {}, {}
    emit, gloss = np.zeros(depth_gt.shape, bool), np.zeros(depth_gt.shape, bool)
    for i, g in enumerate(train):
        st = scene.frame(g, W, H)
        caster.update(st)
        c = caster.cast_rays()
        emit[i], gloss[i] = _material_masks(c, st)
        if g in need:
            casts[g], states[g] = c, st
    depth_prior = degrade_depth(depth_gt, emit, gloss, profile, make_rng(seed, clip_key, "depth"))
    for i, g in enumerate(train):
        writer.write_prior_depth(g, depth_prior[i])

    gt_tracks = load_trackset(out / "gt/tracks.npz")
    cols = [list(gt_tracks.frames).index(g) for g in train]
    gt_train = TrackSet(
        tracks=gt_tracks.tracks[:, cols],
        visible=gt_tracks.visible[:, cols],
        frames=np.array(train, np.int64),
        dynamic=gt_tracks.dynamic,
    )
    writer.write_prior_tracks(
        degrade_tracks(gt_train, depth_gt, W, H, profile, make_rng(seed, clip_key, "tracks"))
    )

    dt_of = dict(zip(train, train_dt))
    ldr_of = {g: mio.read_png(out / "input/ldr" / frame_name(g, "png")) for g in need}
    flows, valids = [], []
    for k, (a, b) in enumerate(pairs):
        f, v = flow_between(
            casts[a], states[b], states[b], casts[b].depth, casts[b].instance, cam_a=states[a]
        )
        f2, v2 = degrade_flow(
            f,
            v,
            ldr_of[a],
            ldr_of[b],
            exposure_gap_ev(dt_of[a], dt_of[b]),
            profile,
            make_rng(seed, clip_key, "flow", k),
        )
        flows.append(f2)
        valids.append(v2)
    if pairs:
        writer.write_prior_flow(
            FlowSet(np.array(pairs, np.int64), np.stack(flows), np.stack(valids))
        )
    meta.priors = priors_metadata(profile, seed)


def _record_clip_stats(job: _Job, meta: ClipMeta, hdr_train: Dict[int, np.ndarray]) -> None:
    """clip.json gt.dynamic_fraction (mean over frames) and gt.dynamic_range_stops."""
    out = job.out
    meta.gt["dynamic_fraction"] = float(
        np.mean(
            [
                (mio.read_png(out / "gt/masks/dynamic" / frame_name(g, "png")) > 127).mean()
                for g in job.frames
            ]
        )
    )
    meta.gt["dynamic_range_stops"] = dynamic_range_stops(hdr_train.values())


def _finish(job: _Job, writer: ClipWriter, meta: ClipMeta, targets, allow_misplaced) -> None:
    """Step 6: what the clip achieved, measured from its PNGs (gt.placement); clip.json is written
    last, the unit-scale frames removed, and a placement miss raised (or warned about)."""
    meta.gt["placement"] = measure_placement(job.out, meta, targets)
    writer.meta = meta
    writer.finalize()
    # gt/hdr holds the same frames, scaled
    shutil.rmtree(job.out.joinpath(*UNIT_HDR_DIR), ignore_errors=True)
    check_clip_placement(
        job.out, meta.gt["placement"], allow_misplaced, job.scene_path, job.gen["preset"]
    )


class PlacementError(InputError):
    """A finished clip misses its exposure-placement targets (benchgen.placement)."""


def check_clip_placement(
    clip_dir,
    placement: Optional[dict],
    allow_misplaced: bool = False,
    scene_path=None,
    preset: Optional[str] = None,
) -> None:
    """Raise PlacementError naming every missed target (unless allow_misplaced; then only a line on
    stderr).

    scene_path: the clip's scene spec. What the message offers depends on whose spec it is: the
    user's own spec is to be changed; a shipped smoke-test scene (every shipped suite listing it
    sets `placement: warn`, as the tiny suite does) is expected to miss targets, so when allowed
    the miss is only a note; another shipped scene is meant to meet them: its miss is to report."""
    import sys

    from .placement import placement_failures
    from .suite import builtin_scene_suites, is_builtin_scene

    if not placement:
        return
    bad = placement_failures(placement)
    if not bad:
        return
    missed = "; ".join(bad)
    at = f" at preset {preset}" if preset else ""
    if scene_path is None or not is_builtin_scene(scene_path):
        msg = (
            f"{clip_dir}: the clip misses its exposure-placement targets (clip.json "
            f"gt.placement): {missed}. Change the scene spec (deeper shadows, an unlit corner, "
            "smaller or dimmer lamps; docs/exposure.md) or pass --allow-misplaced to keep the clip "
            "anyway."
        )
        if allow_misplaced:
            print("warning: " + msg, file=sys.stderr)
            return
        raise PlacementError(msg)
    name = Path(scene_path).stem
    suites = builtin_scene_suites(scene_path)
    if suites and all(s.placement == "warn" for s in suites):
        msg = (
            f"{clip_dir}: the built-in smoke-test scene {name} misses exposure-placement "
            f"targets{at} ({missed}): expected for this scene (suite "
            f"{', '.join(s.name for s in suites)} sets `placement: warn`, docs/exposure.md) and "
            "harmless; the clip is usable, and clip.json gt.placement records what it achieved"
        )
        if allow_misplaced:
            print(f"note: {msg}.", file=sys.stderr)
            return
        raise PlacementError(msg + "; pass --allow-misplaced to keep it.")
    msg = (
        f"{clip_dir}: the built-in scene {name} misses its exposure-placement targets{at} "
        f"(clip.json gt.placement): {missed}. Shipped benchmark scenes are meant to meet them "
        "(docs/exposure.md), so please report this with the clip.json; pass --allow-misplaced "
        "to keep the clip anyway."
    )
    if allow_misplaced:
        print("warning: " + msg, file=sys.stderr)
        return
    raise PlacementError(msg)


def _frames_by_level(
    out: Path,
    settings: ExposureSettings,
    train: Sequence[int],
    train_dt: Sequence[float],
    test: Sequence[int],
) -> Dict[float, np.ndarray]:
    """Unit-scale HDR frames of each observed level: the training frames shown at it, or (when the
    schedule puts no training frame exactly at a level, e.g. random-values) the test frames, which
    are rendered at every level."""
    res = {}
    for lv in settings.observed:
        gs = [g for g, dt in zip(train, train_dt) if float(dt) == float(lv)] or list(test)
        res[float(lv)] = np.stack(
            [mio.read_exr(out.joinpath(*UNIT_HDR_DIR, frame_name(g, "exr"))) for g in gs]
        )
    return res


def sibling_clips(root, scene: str) -> List[Path]:
    """Finished clips of `scene` under an output root (root/<setting or suite>/<scene>/clip.json),
    sorted: the candidates make_clip may take a render from."""
    return sorted(c.parent for c in Path(root).glob(f"*/{scene}/clip.json"))


def make_suite(
    suite,
    out_root,
    preset: str = "small",
    scenes: Optional[Sequence[str]] = None,
    priors: str = "realistic",
    schedule: Optional[str] = None,
    num_exposures: Optional[int] = None,
    observed=None,
    novel=None,
    seed: int = 0,
    jobs: int = 1,
    force: bool = False,
    progress: bool = True,
    spp: Optional[int] = None,
    crf: str = "hdrnerf",
    allow_misplaced: bool = False,
    reuse_root=None,
    executor=None,
    frames_per_task: Optional[int] = None,
    log=None,
    render_only: bool = False,
) -> List[Path]:
    """Generate every clip of a suite under out_root/<suite>/<scene>; `jobs` > 1 renders clips in
    parallel processes.

    render_only: only plan each clip and render its HDR frames and views as tasks on `executor`
    (required; m4dgs.core.executors.LocalExecutor renders them on this machine), then stop: the
    same call without it makes the clips from those frames (e.g. render on GPU nodes, make the
    clips elsewhere). Returns the folders of the clips not finished yet, each summarised on `log`
    (render_summary).

    executor: an m4dgs.core.executors.Executor (`benchgen make --executor ray|slurm`): every clip
    is planned first (plan_clip: its light selection, on this process), the HDR frames and views
    still missing in all clips are rendered as tasks of at most `frames_per_task` frames on the
    executor (benchgen.distribute.render_specs; `log` gets a line per task), then each clip is
    made from them here by make_clip, as without an executor. `jobs` must then be 1.

    reuse_root: a root of earlier clips (default out_root); a scene's finished clips there
    (reuse_root/<any suite>/<scene>) are offered to make_clip as render_from.

    Clips that miss their exposure-placement targets are all finished first, then one PlacementError
    lists them (allow_misplaced: only warnings).

    crf: the clips' camera response (m4dgs.core.crf.CLIP_CRFS; the paper's "hdrnerf" by default)."""
    from .exposure import exposure_preset
    from .suite import load_suite

    s = load_suite(suite)
    if (
        num_exposures is not None
        or observed is not None
        or novel is not None
        or schedule is not None
    ):
        settings = exposure_preset(
            num_exposures or len(s.observed),
            schedule or s.schedule,
            observed=observed if observed is not None else (None if num_exposures else s.observed),
            novel=novel if novel is not None else (None if num_exposures else s.novel),
        )
    else:
        settings = ExposureSettings(tuple(s.observed), tuple(s.novel), s.schedule)
    paths = [p for p in s.scenes if scenes is None or p.stem in scenes]
    if scenes is not None:
        missing = sorted(set(scenes) - {p.stem for p in paths})
        if missing:
            raise ValueError(f"suite {s.name!r} has no scene(s) {missing} (it has {s.scene_names})")
    root = Path(out_root) / s.name
    reuse = Path(reuse_root if reuse_root is not None else out_root)
    jobs_list = [(p, root / p.stem, sibling_clips(reuse, p.stem)) for p in paths]
    kw = dict(
        crf=crf, force=force, spp=spp, allow_misplaced=allow_misplaced or s.placement == "warn"
    )
    if render_only and executor is None:
        raise ValueError("render_only renders as tasks on an executor: pass one")
    if executor is not None:
        from .distribute import render_specs, render_summary

        if jobs != 1:
            raise ValueError(f"jobs must be 1 with an executor, got {jobs}")
        specs = []
        for p, o, rf in jobs_list:
            specs += plan_clip(
                p,
                o,
                preset,
                settings,
                priors,
                seed,
                crf=crf,
                force=force,
                spp=spp,
                render_from=rf,
                frames_per_task=frames_per_task,
                threads=executor.threads,
            )
        done = render_specs(executor, specs, log)
        if render_only:
            say = log or (lambda m: print(m, file=sys.stderr, flush=True))
            left = [o for _, o, _ in jobs_list if not (o / "clip.json").exists()]
            for o in left:
                say(f"[benchgen] {o}: " + render_summary(o.joinpath(*UNIT_HDR_DIR), done))
            return left
        kw["force"] = False  # plan_clip started the forced clips over
    # every clip is made even when an earlier one misses its placement targets; the misses are
    # reported together
    results, misplaced = [], []
    if jobs <= 1:
        for p, o, rf in jobs_list:
            try:
                results.append(
                    make_clip(
                        p,
                        o,
                        preset,
                        settings,
                        priors,
                        seed,
                        progress=progress,
                        render_from=rf,
                        **kw,
                    )
                )
            except PlacementError as e:
                misplaced.append(str(e))
    else:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=jobs) as ex:
            futs = [
                ex.submit(
                    make_clip,
                    p,
                    o,
                    preset,
                    settings,
                    priors,
                    seed,
                    progress=False,
                    render_from=rf,
                    **kw,
                )
                for p, o, rf in jobs_list
            ]
            for f in futs:
                try:
                    results.append(f.result())
                except PlacementError as e:
                    misplaced.append(str(e))
    if misplaced:
        raise PlacementError("\n".join(misplaced))
    return results
