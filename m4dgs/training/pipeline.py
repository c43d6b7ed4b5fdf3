"""`m4dgs train`: the whole method on one clip, resumable (the run folder: docs/outputs.md).

Phases (status.json records the last finished one; each writes its result atomically before the next
starts):

1. camera_init  dynamic masks from the prior flow (epipolar error maps), MoSca-style cameras and
   bundle adjustment
                -> model/camera_init.pt, cameras_ba.json
2. stage1       video HDR Gaussians (m4dgs.training.stage1), checkpointed every `checkpoint_every`
   iterations to model/ckpt.pt
                -> model/stage1.pt, renders/stage1/{hdr,depth}/<g>.exr, renders/stage1/ldr/<g>.png
3. v2w          video-to-world transform (m4dgs.training.v2w) -> model/v2w.pt
4. stage2       world Gaussians + camera refinement (m4dgs.training.stage2), checkpointed ->
   model/final.pt, cameras.json
5. render       renders/{train,test}/... (m4dgs.outputs.render.render_run)  -> status "done"

A killed run restarts from the last checkpoint of the phase it was in. Only the clip's training
frames, exposure times and priors are read (never gt/). Every phase starts from the global torch
generator seeded with the trainer seed, so its result does not depend on which phases ran before it
in the same process.

With `share_dir`, phases 1-4 are shared between runs of the same clip whose configurations agree on
everything those phases read (stage 2: the whole configuration and the variant;
m4dgs.training.phases)."""

from __future__ import annotations

import os
import shutil
import time
import warnings
from pathlib import Path
from typing import Any, Dict, List, Optional

import numpy as np
import torch

from m4dgs.clip import Cameras, Clip, TrackSet, frame_name, frame_time
from m4dgs.core import camera as cam
from m4dgs.core import spline
from m4dgs.core.device import peak_memory_mib, resolve_device
from m4dgs.core.errors import InputError
from m4dgs.core.host import cpu_capability, gpu_name, host_info
from m4dgs.core.io import read_exr, write_exr, write_json, write_png
from m4dgs.core.lock import FolderLock
from m4dgs.core.threads import kernel_threads
from m4dgs.model.gaussians import VideoGaussians, WorldGaussians, init_video_gaussians
from m4dgs.outputs.render import render_run
from m4dgs.priors.camera_init import initialize_cameras
from m4dgs.priors.epipolar import dynamic_masks, epipolar_error_maps, opencv_flow_prior
from m4dgs.priors.rigidity import rigidity_masks
from m4dgs.run import RunDir, load_torch, save_torch
from m4dgs.training.config import TrainConfig, to_dict, upgrade_dict, validate
from m4dgs.training.data import (
    TrainingData,
    frames_and_exposures,
    init_tracks,
    load_training_data,
)
from m4dgs.training.exposure import training_exposures
from m4dgs.training.phases import SHARED_PHASES, PhaseCache, code_fingerprint, phase_keys
from m4dgs.training.stage1 import VideoStage, build_appearance, train_stage1
from m4dgs.training.stage2 import WorldInit, WorldStage, train_stage2
from m4dgs.training.v2w import transform
from m4dgs.training.variants import variant_config

PHASES = ("camera_init", "stage1", "v2w", "stage2", "render", "done")


def resolve_config(
    clip: Clip,
    preset: str = "small",
    variant: str = "full",
    overrides: Optional[Dict[str, Any]] = None,
) -> TrainConfig:
    """Preset defaults, then the variant's overrides (a variant without stage 1 gets stage 1's
    iterations in stage 2: m4dgs.training.variants.variant_config), then the user's; the processing
    size is the clip's."""
    cfg = variant_config(preset, variant, overrides)
    cfg.width, cfg.height = clip.width, clip.height
    return cfg


def _phase_index(status: Dict[str, Any]) -> int:
    """Index of the first phase still to run."""
    last = status.get("finished")
    return 0 if last is None else PHASES.index(last) + 1


class Trainer:
    """Runs the phases of one (clip, variant) into a run folder."""

    def __init__(
        self,
        clip_dir,
        run_dir,
        preset: str = "small",
        variant: str = "full",
        overrides: Optional[Dict[str, Any]] = None,
        device: str = "auto",
        progress: bool = True,
        backend: Optional[str] = None,
        share_dir=None,
    ):
        self.clip = Clip.open(clip_dir)
        self.share = PhaseCache(share_dir) if share_dir is not None else None
        self.run = RunDir(run_dir)
        self.device = resolve_device(device)
        self.progress = progress
        cfg = resolve_config(self.clip, preset, variant, overrides)
        if backend is not None:
            cfg.raster_backend = backend
        # bad option values fail here, not after minutes of camera initialisation and stage 1
        validate(cfg)
        self.variant = variant
        want = to_dict(cfg)
        have = self.run.read_config()
        if have is not None and have != want and upgrade_dict(have, warn=False) == want:
            # a run of an older version with the same settings: its config in the current layout
            self.run.write_config(want)
            have = want
        if have is not None and have != want:
            diff = sorted(k for k in set(have) | set(want) if have.get(k) != want.get(k))
            raise InputError(
                f"{self.run.config_path}: an existing run with a different configuration "
                f"(sections {diff}); "
                "use another --out or --force"
            )
        self.cfg = cfg
        self.run.root.mkdir(parents=True, exist_ok=True)
        if have is None:
            self.run.write_config(want)
        stray = self.clip.stray_inputs()
        if stray:
            names = ", ".join(str(p.relative_to(self.clip.root)) for p in stray[:3])
            more = f" and {len(stray) - 3} more" if len(stray) > 3 else ""
            warnings.warn_explicit(  # one line, "m4dgs clip:0: UserWarning: ..."
                f"{self.clip.root}: {len(stray)} file(s) in input/ that the clip does not use "
                f"({names}{more}): the trainer reads only input/ldr/<training frame>.png; move "
                "them out (they still count in the clip's input fingerprint)",
                UserWarning,
                "m4dgs clip",
                0,
                module=__name__,
            )
        self.fingerprint = self.clip.input_fingerprint()
        self._check_inputs_unchanged()
        self.data: TrainingData = load_training_data(self.clip, self.device)
        self.seconds: Dict[str, float] = dict(self.run.status().get("stage_seconds", {}))
        self._write_run_info()

    def _check_inputs_unchanged(self) -> None:
        """Record the clip's input fingerprint (m4dgs.clip.Clip.input_fingerprint) in status.json
        when the run starts; refuse to resume a run whose clip inputs changed since (its camera
        initialisation, stage-1 and V2W outputs would be stale)."""
        status = self.run.status()
        now = self.fingerprint
        before = status.get("clip_fingerprint")
        if before is None:
            if status.get("stage", "new") == "new":
                self.run.set_status(clip_fingerprint=now)
            return  # a run of an older version: nothing to compare with
        if before != now:
            raise InputError(
                f"{self.run.root}: the clip {self.clip.root} changed since this run started "
                "(clip.json, input/ or priors/); its finished phases were computed on the old "
                "inputs. Use --force to start over, or another --out"
            )

    def _write_run_info(self, **extra) -> None:
        info = {
            "clip": os.path.relpath(self.clip.root.resolve(), self.run.root.resolve()),
            "clip_abs": str(self.clip.root.resolve()),
            "variant": self.variant,
            "preset": self.cfg.preset,
            "method": self.cfg.method,
            "device": str(self.device),
            "torch_threads": torch.get_num_threads(),
            "kernel_threads": kernel_threads(),
            # the m4dgs sources the run was trained with (m4dgs.training.phases.code_fingerprint):
            # exported beside the metrics, so a table can tell runs of different code apart
            "code": code_fingerprint(),
            # where it ran: across machines a seed need not repeat bit for bit (m4dgs.core.host)
            "host": host_info(self.device),
            **extra,
        }
        write_json(self.run.path("run.json"), info)

    # -- bookkeeping
    # ----------------------------------------------------------------------------------------------
    def _finish(self, phase: str, seconds: float) -> None:
        self.seconds[phase] = self.seconds.get(phase, 0.0) + seconds
        self.run.set_status(
            stage=PHASES[PHASES.index(phase) + 1], finished=phase, stage_seconds=self.seconds
        )

    def _progress_seconds(self, phase: str, seconds: float) -> None:
        self.seconds[phase] = self.seconds.get(phase, 0.0) + seconds
        self.run.set_status(stage=phase, stage_seconds=self.seconds)

    def _log_fn(self, stage: str, stage_obj, start_time: float):
        every = max(int(self.cfg.checkpoint_every), 1)
        n_total = getattr(self.cfg, stage).iterations

        def on_step(it: int, rec: Dict[str, float]) -> None:
            rec = {"stage": stage, "step": it, **rec}
            self.run.log(rec)
            if (it + 1) % every == 0 and it + 1 < n_total:
                self.run.write_checkpoint(
                    {"stage": stage, "step": it + 1, "state": stage_obj.state_dict()}
                )
                self._progress_seconds(stage, time.perf_counter() - start_time[0])
                start_time[0] = time.perf_counter()

        return on_step

    def _checkpoint(self, stage: str) -> Optional[Dict[str, Any]]:
        """The newest readable mid-stage checkpoint (model/ckpt.pt, else model/ckpt.prev.pt:
        RunDir.read_checkpoint) if it belongs to `stage`, else None."""
        ck = self.run.read_checkpoint(map_location=self.device)
        return ck if ck is not None and ck.get("stage") == stage else None

    def _resume(self, stage: str, stage_obj, ck: Optional[Dict[str, Any]] = None) -> int:
        """Load `ck` (or the checkpoint on disk) into stage_obj; returns the step to continue from
        (0 = none). The log keeps the stage's lines up to that step only: the lines of an attempt
        killed (or failing a write) after it, or before the stage's first checkpoint, go."""
        ck = self._checkpoint(stage) if ck is None else ck
        if ck is None:
            self.run.truncate_log(stage, -1)
            return 0
        stage_obj.load_state_dict(ck["state"])
        self.run.truncate_log(stage, ck["step"] - 1)
        return int(ck["step"])

    # -- phases
    # ----------------------------------------------------------------------------------------------
    def camera_init(self) -> None:
        t0 = time.perf_counter()
        d, cfg = self.data, self.cfg
        if self.clip.has_flow_prior():
            fs = self.clip.load_flow_prior()
        else:
            ldr = [self.clip.load_ldr(g) for g in d.frames]
            fs = opencv_flow_prior(ldr, self.clip.train_dt.tolist(), d.frames)
        emaps = epipolar_error_maps(fs, d.frames, cfg.epipolar)
        masks_epi = dynamic_masks(emaps, cfg.epipolar.threshold)
        ts = TrackSet(d.tracks.cpu().numpy(), d.track_vis.cpu().numpy(), np.asarray(d.frames))
        depth = d.depth.cpu()
        bar = "camera init: bundle adjustment" if self.progress else ""
        res = initialize_cameras(
            ts, depth, masks_epi, d.width, d.height, cfg.camera_init, progress=bar
        )
        if "warning" in res.diagnostics and not cfg.camera_init.allow_fallback:
            n = res.diagnostics
            raise InputError(
                f"{self.clip.root}: camera initialisation failed: {n['warning']} "
                f"({n.get('num_used', 0)} static tracks usable, "
                f"{cfg.camera_init.min_common_points} needed; {n.get('num_tracks', 0)} tracks in "
                "all). Check the tracks and depth priors and the dynamic masks, or pass --set "
                "camera_init.allow_fallback=true to train with identity cameras anyway"
            )
        masks, mask_diag = (
            masks_epi,
            {"method": "epipolar", "fraction_epipolar": float(masks_epi.float().mean())},
        )
        if cfg.masks.method != "epipolar" and "warning" not in res.diagnostics:
            masks, mask_diag, res = self._rigidity_masks(fs, depth, masks_epi, res, ts)
        if cfg.masks.highlight_blobs:
            from m4dgs.priors.highlight_tracks import highlight_masks

            hl = highlight_masks(*frames_and_exposures(d))
            hl_t = torch.from_numpy(hl).to(masks.device)
            mask_diag = {
                **mask_diag,
                "fraction_highlight": float(hl.mean()),
                "fraction_before_highlight": float(masks.float().mean()),
            }
            masks = masks.bool() | hl_t
            mask_diag["fraction"] = float(masks.float().mean())
        save_torch(
            self.run.path("model", "camera_init.pt"),
            {
                "K": res.K.float(),
                "c2w": res.c2w.float(),
                "depth_scale": res.depth_scale.float(),
                "masks": masks.bool(),
                "masks_epipolar": masks_epi.bool(),
                "diagnostics": {
                    **{
                        k: v
                        for k, v in res.diagnostics.items()
                        if isinstance(v, (int, float, str, list, dict))
                    },
                    "masks": mask_diag,
                },
            },
        )
        self._write_cameras("cameras_ba.json", res.K.float(), res.c2w.float())
        self._finish("camera_init", time.perf_counter() - t0)

    def _rigidity_masks(self, fs, depth, masks_epi, res, ts):
        """(masks [T, H, W], diagnostics, camera result) for cfg.masks.method ("reprojection" |
        "union") from the BA result `res`; with refine_cameras the BA is re-run once on these masks
        and the masks recomputed with its cameras (that BA result is returned when it succeeds, else
        `res`)."""

        d, mc = self.data, self.cfg.masks
        index = {g: i for i, g in enumerate(d.frames)}
        keep = [p for p, (a, b) in enumerate(fs.pairs.tolist()) if a in index and b in index]
        pairs = [(index[a], index[b]) for a, b in fs.pairs[keep].tolist()]
        flow, valid = torch.from_numpy(fs.flow[keep]), torch.from_numpy(fs.valid[keep])

        def make(r):
            m = rigidity_masks(depth, r.depth_scale, r.K, r.c2w, flow, valid, pairs, mc)
            return m | masks_epi if mc.method == "union" else m

        masks = make(res)
        diag = {
            "method": mc.method,
            "fraction_epipolar": float(masks_epi.float().mean()),
            "fraction_first_pass": float(masks.float().mean()),
        }
        if mc.refine_cameras:
            bar = "camera init: bundle adjustment on the refined masks" if self.progress else ""
            r2 = initialize_cameras(
                ts, depth, masks, d.width, d.height, self.cfg.camera_init, progress=bar
            )
            if "warning" not in r2.diagnostics:
                r2.diagnostics["first_pass"] = {
                    k: res.diagnostics[k] for k in ("num_static", "fov_final_deg")
                }
                res = r2
                masks = make(res)
        diag["fraction"] = float(masks.float().mean())
        return masks, diag, res

    def _camera_init_result(self):
        return load_torch(self.run.path("model", "camera_init.pt"), map_location=self.device)

    def _write_cameras(self, name: str, K: torch.Tensor, c2w_train: torch.Tensor) -> None:
        """Cameras for every global frame: training frames as given, the others interpolated (slerp
        + lerp)."""
        times = np.array([frame_time(self.clip, g) for g in self.clip.meta.frames])
        c2w_all = cam.interpolate_trajectory(
            np.arange(len(self.data.frames), dtype=np.float64),
            c2w_train.detach().cpu().double().numpy(),
            times,
        )
        G = len(times)
        cams = Cameras(
            np.asarray(self.clip.meta.frames),
            np.tile(K.detach().cpu().double().numpy(), (G, 1, 1)),
            c2w_all,
        )
        write_json(self.run.path(name), cams.to_json())

    def stage1(self) -> None:
        t0 = [time.perf_counter()]
        ck = self._checkpoint("stage1")  # resuming: skip the lift + tone-mapper pre-training
        stage = VideoStage(
            self.data, self.cfg, self.device, self.cfg.raster_backend, init=ck is None
        )
        start = self._resume("stage1", stage, ck)
        train_stage1(stage, start, self._log_fn("stage1", stage, t0), self.progress)
        save_torch(
            self.run.path("model", "stage1.pt"), {**stage.state_dict(), "frames": self.data.frames}
        )
        out = stage.render_training_video()

        for i, g in enumerate(self.data.frames):
            write_exr(
                self.run.path("renders", "stage1", "hdr", frame_name(g, "exr")),
                out["hdr"][i].cpu().numpy(),
            )
            write_exr(
                self.run.path("renders", "stage1", "depth", frame_name(g, "exr")),
                out["depth"][i].cpu().numpy(),
            )
            write_png(
                self.run.path("renders", "stage1", "ldr", frame_name(g, "png")),
                out["ldr"][i].cpu().numpy(),
            )
        self._finish("stage1", time.perf_counter() - t0[0])

    def _stage1_video(self):
        hdr = torch.stack(
            [
                torch.from_numpy(
                    read_exr(self.run.path("renders", "stage1", "hdr", frame_name(g, "exr")))
                )
                for g in self.data.frames
            ]
        ).to(self.device)
        depth = torch.stack(
            [
                torch.from_numpy(
                    read_exr(self.run.path("renders", "stage1", "depth", frame_name(g, "exr")))
                )
                for g in self.data.frames
            ]
        ).to(self.device)
        return hdr, depth

    def v2w(self) -> None:
        t0 = time.perf_counter()
        cfg, d = self.cfg, self.data
        ci = self._camera_init_result()
        masks = ci["masks"].to(self.device)
        if cfg.method == "static-hdr":
            masks = torch.zeros_like(masks)  # every Gaussian static
        if cfg.ablation.use_video_init:
            sd = load_torch(self.run.path("model", "stage1.pt"), map_location=self.device)
            stage = VideoStage(d, cfg, self.device, cfg.raster_backend, init=False)
            stage.load_state_dict(sd)
            video = stage.gauss
            _, depth = self._stage1_video()
            appearance = {
                "color": sd["color"],
                "tonemap": sd["tonemap"],
                "background": sd["background"],
            }
        else:
            # lifted tracks/depth without the video-Gaussian optimisation (ablation (a) and the
            # world-only baselines)
            tracks, vis, always = init_tracks(d, cfg.stage1.init)
            video = init_video_gaussians(
                tracks, vis, d.depth, d.width, d.height, cfg.stage1.init, cfg.model, always=always
            )
            depth = d.depth
            appearance = None
        world, report = _transform_with_scale(transform, video, ci, masks, depth, cfg, d)
        save_torch(
            self.run.path("model", "v2w.pt"),
            {"gaussians": world.to_state(), "appearance": appearance, "report": _plain(report)},
        )
        self._finish("v2w", time.perf_counter() - t0)

    def world_init(self) -> WorldInit:
        """What stage 2 starts from, read from the run's earlier phases: the V2W output's Gaussians
        and appearance (a freshly pre-trained appearance when V2W lifted the priors instead),
        camera initialisation's cameras, depth scales and dynamic masks (none for static-hdr),
        and stage 1's HDR renders (none without video initialisation). bench/step_bench.py builds
        its stage 2 from this too, so that it times the stage the trainer runs."""
        cfg, d = self.cfg, self.data
        ci = self._camera_init_result()
        v = load_torch(self.run.path("model", "v2w.pt"), map_location=self.device)
        c0, _ = training_exposures(cfg.exposure, d, self.device)
        color, tm, bg = build_appearance(cfg, c0, self.device, pretrain=v["appearance"] is None)
        if v["appearance"] is not None:
            color.load_state_dict(v["appearance"]["color"])
            tm.load_state_dict(v["appearance"]["tonemap"])
            bg.load_state_dict(v["appearance"]["background"])
        stage1_hdr = self._stage1_video()[0] if cfg.ablation.use_video_init else None
        return WorldInit(
            WorldGaussians.from_state(v["gaussians"]),
            color,
            tm,
            bg,
            ci["K"],
            ci["c2w"],
            ci["depth_scale"],
            dynamic_masks=ci["masks"] if cfg.method != "static-hdr" else None,
            stage1_hdr=stage1_hdr,
        )

    def stage2(self) -> None:
        t0 = [time.perf_counter()]
        cfg, d = self.cfg, self.data
        init = self.world_init()
        color, tm, bg = init.color, init.tonemap, init.background
        stage = WorldStage(d, cfg, init, self.device, cfg.raster_backend)
        start = self._resume("stage2", stage)
        train_stage2(stage, start, self._log_fn("stage2", stage, t0), self.progress)
        c2w = stage.cameras().detach()
        save_torch(
            self.run.path("model", "final.pt"),
            {
                "gaussians": stage.gauss.to_state(),
                "color": color.state_dict(),
                "tonemap": tm.state_dict(),
                "background": bg.state_dict(),
                "K": stage.rig.K.detach().cpu(),
                "c2w": c2w.cpu(),
                "frames": d.frames,
                "log2_dt": stage.log2_dt.cpu(),
                "config": to_dict(cfg),
                "variant": self.variant,
                "feature_dim": cfg.model.feature_dim,
            },
        )
        self._write_cameras("cameras.json", stage.rig.K, c2w)
        self._finish("stage2", time.perf_counter() - t0[0])

    def render(self) -> None:
        t0 = time.perf_counter()
        render_run(self.run.root, device=str(self.device), progress=self.progress)
        self._finish("render", time.perf_counter() - t0)

    # -- sharing
    # ----------------------------------------------------------------------------------------------
    def phase_keys(self) -> Dict[str, str]:
        """{phase: share key} of this run (m4dgs.training.phases.phase_keys)."""
        from m4dgs.raster import resolve_backend

        context = {
            "clip": self.fingerprint,
            "code": code_fingerprint(),
            "torch": torch.__version__,
            # float sums add up in another order with another thread count (1 vs 2 threads moved
            # tiny runs' LDR PSNR by up to 0.6 dB): a shared phase must come from the same count
            "threads": torch.get_num_threads(),
            "kernel_threads": kernel_threads(),
            "device": self.device.type,
            "backend": resolve_backend(self.cfg.raster_backend, self.device),
            # another instruction set (AVX2 / AVX512) or another GPU rounds differently, so a share
            # folder on a network disk must not hand one machine's phase to another
            "cpu_capability": cpu_capability(),
            "gpu": gpu_name(self.device),
        }
        return phase_keys(to_dict(self.cfg), context, self.variant)

    def _shared(self, phase: str, compute) -> None:
        """Run `phase` through the share folder: copy it when an entry with this run's key exists,
        else compute it (holding the entry's lock, so that a concurrent run with the same key waits)
        and publish it."""
        key = self.phase_keys()[phase]
        with self.share.lock(phase, key):
            entry = self.share.get(phase, key)
            if entry is None:
                compute()
                log = [r for r in self.run.read_log() if r.get("stage") == phase]
                self.share.put(phase, key, self.run.root, self.seconds.get(phase, 0.0), log)
                return
            self.share.copy_into(entry, phase, self.run.root)
        self.run.truncate_log(phase, -1)  # lines of an interrupted attempt at this phase
        self.run.log_records(entry.log)
        ck = self.run.read_checkpoint()
        if ck is not None and ck.get("stage") == phase:
            for p in (self.run.ckpt_path, self.run.prev_ckpt_path):
                p.unlink(missing_ok=True)
        shared = dict(self.run.status().get("shared_phases", {}))
        shared[phase] = {"key": key, "from": entry.producer}
        self.run.set_status(shared_phases=shared)
        # the producer's compute time: the run reports what the method costs
        self.seconds[phase] = 0.0
        self._finish(phase, entry.seconds)

    # -- all
    # ----------------------------------------------------------------------------------------------
    def run_phase(self, phase: str) -> None:
        """Run one phase (the method of that name) from the trainer seed's generator state,
        whatever ran before it in this process: a phase computes the same whether it follows the
        phases before it here, in another process (a resumed run) or in another run (a shared
        phase). With a share folder, a shared phase (SHARED_PHASES) is copied from it when there,
        else computed and published (`_shared`). `train` runs every phase through this; tools
        that run or time phases one by one call it too."""
        torch.manual_seed(self.cfg.seed)
        compute = getattr(self, phase)
        if self.share is not None and phase in SHARED_PHASES:
            self._shared(phase, compute)
        else:
            compute()

    def _load_rasterizer(self) -> None:
        """Load (on its first use: compile, with a message) the rasterizer before any phase, so
        that no progress bar sits on its first step meanwhile with an ETA set by the compile."""
        from m4dgs.raster import resolve_backend
        from m4dgs.raster.cpu_backend import load_extension

        if resolve_backend(self.cfg.raster_backend, self.device) == "cpu":
            load_extension()

    def train(self) -> Path:
        status = self.run.status()
        if status.get("stage") == "done":
            return self.run.root
        first = _phase_index(status)
        self._load_rasterizer()
        for phase in PHASES[first:-1]:
            if phase == "stage1" and not self.cfg.ablation.use_video_init:
                self._finish("stage1", 0.0)
                continue
            self.run_phase(phase)
        for p in (self.run.ckpt_path, self.run.prev_ckpt_path):  # a finished run needs neither
            if p.exists():
                p.unlink()
        train_seconds = sum(v for k, v in self.seconds.items() if k != "render")
        self._write_run_info(
            train_seconds=train_seconds,
            stage_seconds=self.seconds,
            num_gaussians=_num_gaussians(self.run),
            peak_memory_mib=peak_memory_mib(self.device),
        )
        return self.run.root


def _plain(x):
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if torch.is_tensor(x):
        return x.tolist()
    if isinstance(x, (np.generic,)):
        return x.item()
    return x


def _num_gaussians(run: RunDir) -> Optional[int]:
    p = run.path("model", "final.pt")
    if not p.exists():
        return None
    g = load_torch(p)["gaussians"]
    return int(g["static"]["means"].shape[0] + g["dynamic"]["ctrl"].shape[0])


def _transform_with_scale(transform, video, ci, masks, depth, cfg, d):
    """V2W with the bundle-adjustment depth scales: video z (prior units) becomes world depth z *
    s_t per frame (the other attributes, the gain over time included, are the video Gaussians')."""

    s = ci["depth_scale"].to(video.knots)
    times = torch.arange(d.num_frames, dtype=video.knots.dtype, device=video.knots.device)
    # rescale the video trajectory's depth per frame and refit the control points on the same knots
    with torch.no_grad():
        pos = spline.evaluate(video.params["ctrl"], video.knots, times)  # [N, T, 3]
        pos = torch.cat([pos[..., :2], pos[..., 2:3] * s[None, :, None]], -1)
        ctrl = spline.fit_control_points(pos, None, times, video.knots)
    scaled = VideoGaussians(
        ctrl,
        video.params["rot"].detach(),
        video.params["scales"].detach(),
        video.params["opacities"].detach(),
        video.params["features"].detach(),
        video.knots,
        video.num_frames,
        video.scale_kind,
        video.scale_max,
        log2_gain=None if video.gain_values() is None else video.gain_values().detach(),
    )
    return transform(
        scaled,
        ci["K"],
        ci["c2w"],
        masks,
        depth * s[:, None, None],
        cfg.v2w,
        cfg.ablation,
        d.width,
        d.height,
        world_scale_kind=cfg.model.world_scale_activation,
        world_scale_max=cfg.model.world_scale_max,
    )


def train(
    clip_dir,
    run_dir,
    preset: str = "small",
    variant: str = "full",
    overrides: Optional[Dict[str, Any]] = None,
    device: str = "auto",
    progress: bool = True,
    backend: Optional[str] = None,
    share_dir=None,
) -> Path:
    """Train one variant on one clip into run_dir (resumes; returns at once when the run is
    done). The run folder is locked meanwhile: a second process writing it is refused
    (RunInUseError naming the first one's PID). share_dir: a folder where camera initialisation,
    stage 1, V2W and stage 2 are shared with other runs of the same clip
    (m4dgs.training.phases)."""
    Clip.open(clip_dir)  # not a clip: say so before any folder is made
    made = _missing_folders(Path(run_dir))
    fresh = bool(made)
    try:
        with FolderLock(run_dir):
            trainer = Trainer(
                clip_dir, run_dir, preset, variant, overrides, device, progress, backend, share_dir
            )
            return trainer.train()
    except InputError:
        # refused input (clip, config, priors) before any phase finished: leave no half-made
        # run folder behind (a folder that existed before, or holds a finished phase, is kept)
        if fresh and RunDir(run_dir).status().get("finished") is None:
            shutil.rmtree(run_dir, ignore_errors=True)
            for parent in made[1:]:  # and the parents made for it (runs/<clip>/), when empty
                try:
                    parent.rmdir()
                except OSError:  # another run's folder is in it (or it is gone): keep it
                    break
        raise


def _missing_folders(path: Path) -> List[Path]:
    """`path` and those of its parents that do not exist yet, deepest first."""
    out: List[Path] = []
    p = path.absolute()
    while not p.exists() and p != p.parent:
        out.append(p)
        p = p.parent
    return out
