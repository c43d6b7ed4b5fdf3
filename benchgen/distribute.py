"""`benchgen make --executor ray|slurm`: a suite's HDR renders as frame-range tasks on an executor
(m4dgs.core.executors), the rest of each clip made by benchgen.make as always (docs/cluster.md).

A clip's renders are the unit-scale HDR frames of step 2 (one per frame, into
.benchgen/hdr_unit/) and the held-out views of every test frame (step 2b, into
.benchgen/hdr_unit/views/<view>/). `plan_clip` does what comes before them on the driver (the
resume state, a reused render, the light selection of step 1) and splits the renders still missing
into RenderSpecs of at most `frames_per_task` frames; `render_task` renders one wherever the
executor runs it, and `render_specs` runs them all. make_clip then finds the frames on disk, as it
finds those of a resumed clip, and makes the clip from them by the same code as a local run.

What keeps the bytes equal to a local run:

- every frame is rendered with its own seeds (RenderSettings.seed + g for a frame, view_seed for a
  view), by a Renderer built from frame 0 and moved to the frame, as the local pass does (Mitsuba's
  result does not depend on the frames rendered before, nor on its thread count);
- the task renders with the Mitsuba variant the driver picked, and the light selection the driver
  chose (both in the spec);
- a frame's adaptive samples (gt.render.adaptive_extra_spp_mean) and render time
  (gt.timing_s_per_frame.render) go into a small JSON beside the frame (.benchgen/hdr_unit/stats/),
  which the ground-truth pass counts as if it had rendered the frame itself.

Every file is written atomically and a frame already on disk is skipped, so a rerun task (a lost
Ray worker) or a rerun command continues where the last one stopped.
"""

from __future__ import annotations

import dataclasses
import hashlib
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence, Tuple

from m4dgs.core.errors import InputError, M4DGSError

#: frames (or test frames, for the views) of one render task unless --frames-per-task says
DEFAULT_FRAMES_PER_TASK = 8
#: where a task-rendered frame's statistics wait beside the unit-scale frames
STATS_DIR = "stats"


@dataclass(frozen=True)
class RenderSpec:
    """One render task: `frames` of one clip.

    kind "frames": the unit-scale HDR frames g of `frames` into `hdr_dir` (the clip's
    .benchgen/hdr_unit/); kind "views": every held-out view (the spec's camera.views) of the test
    frames `frames` into hdr_dir/views/<view>/. render: RenderSettings fields with the clip's light
    selection resolved; variant: the Mitsuba variant to render with; spec_sha256: the scene spec's
    bytes as the driver read them (a worker that sees another file refuses); threads: Mitsuba's
    threads in the task."""

    name: str
    hdr_dir: str
    scene_path: str
    spec_sha256: str
    width: int
    height: int
    render: dict
    variant: str
    kind: str
    frames: Tuple[int, ...]
    threads: Optional[int] = None

    @property
    def gpus(self) -> int:
        """1 when the variant renders on CUDA (cuda_ad_rgb, ...), else 0."""
        return 1 if self.variant.startswith("cuda") else 0


def frame_chunks(frames: Sequence[int], per_task: int) -> List[Tuple[int, ...]]:
    """`frames` (in their order) cut into consecutive chunks of at most `per_task`."""
    if int(per_task) < 1:
        raise InputError(f"--frames-per-task must be >= 1, got {per_task!r}")
    fs = [int(g) for g in frames]
    return [tuple(fs[i : i + per_task]) for i in range(0, len(fs), per_task)]


def file_sha256(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def read_frame_stats(hdr_dir, frames: Sequence[int]) -> Dict[int, dict]:
    """{g: {"extra_spp", "seconds"}} of the frames of `frames` that a render task rendered into
    `hdr_dir` (a clip's .benchgen/hdr_unit: their stats JSON is there; frames rendered by
    make_clip itself have none)."""
    from m4dgs.clip import frame_name
    from m4dgs.core import io as mio

    d = Path(hdr_dir) / STATS_DIR
    out = {}
    for g in frames:
        p = d / frame_name(int(g), "json")
        if p.exists():
            out[int(g)] = mio.read_json(p)
    return out


# --------------------------------------------------------------------------------------------------
# On the worker
# --------------------------------------------------------------------------------------------------
def render_task(spec: RenderSpec) -> dict:
    """Render the frames of `spec` that are not on disk yet; returns {"name", "rendered": [g ...],
    "seconds"}. Raises InputError when the scene spec on this worker is not the driver's."""
    t0 = time.perf_counter()
    path = Path(spec.scene_path)
    if not path.exists() or file_sha256(path) != spec.spec_sha256:
        raise InputError(
            f"{path}: the scene spec on this worker is missing or differs from the driver's "
            "(every node must see the same scene files at the same path)"
        )
    from .render import use_variant

    use_variant(spec.variant)
    import drjit as dr

    before = dr.thread_count()
    if spec.threads:
        dr.set_thread_count(int(spec.threads))
    try:
        if spec.kind == "frames":
            done = _render_frames(spec)
        elif spec.kind == "views":
            done = _render_views(spec)
        else:
            raise ValueError(f"render task {spec.name}: unknown kind {spec.kind!r}")
    finally:
        dr.set_thread_count(before)
    return {
        "name": spec.name,
        "kind": spec.kind,
        "hdr_dir": spec.hdr_dir,
        "rendered": done,
        "seconds": round(time.perf_counter() - t0, 2),
    }


def _scene_and_renderer(spec: RenderSpec):
    """The scene (textures band-limited for the clip's grid) and a Renderer built from frame 0, as
    make_clip builds them."""
    from .render import Renderer, RenderSettings
    from .scene import load_scene

    W, H = spec.width, spec.height
    scene = load_scene(spec.scene_path, band_limit=(W, H))
    r = Renderer(scene.frame(0, W, H), W, H, RenderSettings(**spec.render))
    return scene, r


def _render_frames(spec: RenderSpec) -> List[int]:
    from m4dgs.clip import frame_name
    from m4dgs.core import io as mio

    d = Path(spec.hdr_dir)
    todo = [g for g in spec.frames if not (d / frame_name(g, "exr")).exists()]
    if not todo:
        return []
    scene, r = _scene_and_renderer(spec)
    for g in todo:
        r.update(scene.frame(g, spec.width, spec.height))
        t0 = time.perf_counter()
        hdr = r.render_hdr()  # seed settings.seed + g, as the ground-truth pass renders it
        stats = {"extra_spp": r.last_extra_spp, "seconds": time.perf_counter() - t0}
        # the stats first: a frame on disk always has its stats (the frame marks it done)
        mio.write_json(d / STATS_DIR / frame_name(g, "json"), stats)
        mio.write_exr(d / frame_name(g, "exr"), hdr)
    return todo


def _render_views(spec: RenderSpec) -> List[int]:
    """The held-out views of the test frames, as benchgen.make._render_views renders them (the
    look-at distance from the test frame's ray cast; a view with a placement problem or a frame
    without a surface is left to make_clip, which names it)."""
    import numpy as np

    from m4dgs.clip import frame_name
    from m4dgs.core import io as mio

    from .views import pivot_distance, placement_problem, view_c2w, view_seed, view_state

    d = Path(spec.hdr_dir) / "views"
    spec_views = None
    done = []
    scene = r = None
    for g in spec.frames:
        if scene is None:
            scene, r = _scene_and_renderer(spec)
            spec_views = scene.spec["camera"]["views"]
        need = [
            (i, v)
            for i, v in enumerate(spec_views)
            if not (d / v["name"] / frame_name(g, "exr")).exists()
        ]
        if not need:
            continue
        st = scene.frame(g, spec.width, spec.height)
        r.update(st)
        cast = r.cast_rays()
        dist, surface = pivot_distance(cast.depth), float(cast.hit.mean())
        if not np.isfinite(dist):
            continue
        for i, v in need:
            r.update(view_state(st, view_c2w(st.c2w, dist, v["orbit_deg"], v["offset"])))
            if placement_problem(r.cast_rays().depth, dist, surface) is not None:
                continue
            hdr = r.render_hdr(seed=view_seed(r.settings.seed, i, g))
            mio.write_exr(d / v["name"] / frame_name(g, "exr"), hdr)
        done.append(int(g))
    return done


# --------------------------------------------------------------------------------------------------
# On the driver
# --------------------------------------------------------------------------------------------------
class RenderTaskError(M4DGSError):
    """Render tasks failed; the message names each one and its error."""


def render_specs(
    executor, specs: Sequence[RenderSpec], log: Optional[Callable[[str], None]] = None
) -> List[dict]:
    """Run `specs` on `executor` (each a Task of its threads and GPUs), one line per finished task
    and a progress line on `log` (default stderr); returns the tasks' results in finishing order.
    Raises RenderTaskError naming every failed task once all have finished."""
    from m4dgs.core.executors import Progress, Task

    say = log or (lambda m: print(m, file=sys.stderr, flush=True))
    tasks = [Task(s.name, render_task, (s,), threads=executor.threads, gpus=s.gpus) for s in specs]
    if not tasks:
        return []
    prog = Progress(len(tasks), executor.slots, "render tasks")
    results, failed = [], []
    for o in executor.map(tasks):
        prog.add(o.error is None)
        if o.error is None:
            results.append(o.result)
            n = len(o.result["rendered"])
            say(f"[benchgen] rendered {o.task.name} ({n} frame(s), {o.result['seconds']} s)")
        else:
            failed.append(f"{o.task.name}: {o.error}")
            say(f"[benchgen] failed {o.task.name}: {o.error}")
            tb = getattr(o.error, "remote_traceback", None)
            if tb:
                say(tb.rstrip())
        say(f"[benchgen] {prog.line()}")
    if failed:
        raise RenderTaskError(
            f"{len(failed)} of {len(tasks)} render task(s) failed (run the command again to "
            "retry them; finished frames are kept):\n  " + "\n  ".join(failed)
        )
    return results


def render_summary(hdr_dir, results: Sequence[dict]) -> str:
    """One line on what the render tasks of `results` (render_task's) did for the clip whose
    unit-scale frames are in `hdr_dir`: its frames on disk, the frames these tasks rendered and
    their median render seconds a frame (the stats beside each frame: the render alone), and the
    test frames whose views they rendered with the seconds a test frame (task time, scene loading
    and ray casts included)."""
    import statistics

    d = Path(hdr_dir).resolve()  # a task's hdr_dir is absolute, --out may be relative
    mine = [r for r in results if "hdr_dir" in r and Path(r["hdr_dir"]).resolve() == d]
    frames = sorted(g for r in mine if r.get("kind") == "frames" for g in r["rendered"])
    stats = read_frame_stats(d, frames)
    on_disk = len(list(d.glob("*.exr"))) if d.is_dir() else 0
    parts = [f"{on_disk} HDR frame(s) on disk"]
    if stats:
        secs = [float(v["seconds"]) for v in stats.values()]
        parts.append(
            f"{len(frames)} rendered now, median {statistics.median(secs):.2f} s a frame "
            f"(range {min(secs):.2f}-{max(secs):.2f})"
        )
    views = [r for r in mine if r.get("kind") == "views" and r["rendered"]]
    if views:
        n = sum(len(r["rendered"]) for r in views)
        t = sum(float(r["seconds"]) for r in views)
        parts.append(f"views of {n} test frame(s) rendered now, {t / n:.2f} s a test frame")
    return "; ".join(parts) + " (render only: the same command without it makes the clip)"


def clip_specs(job, hdr_dir, frames_per_task: int, threads: Optional[int]) -> List[RenderSpec]:
    """The render tasks of a planned clip (benchgen.make._Job after step 1) whose unit-scale frames
    go to `hdr_dir`: its missing frames (none once the ground truth is done) and its missing views
    (none once they are done), in chunks of `frames_per_task`."""
    from m4dgs.clip import frame_name

    from .render import pick_variant

    state, d = job.state, Path(hdr_dir)
    frames = (
        []
        if "gt_notes" in state
        else [g for g in job.frames if not (d / frame_name(g, "exr")).exists()]
    )
    views = job.scene.spec["camera"]["views"]
    tests = []
    if "views_notes" not in state and views:
        tests = [
            g
            for g in job.test
            if any(not (d / "views" / v["name"] / frame_name(g, "exr")).exists() for v in views)
        ]
    if not frames and not tests:
        return []
    base = dict(
        hdr_dir=str(d.resolve()),
        scene_path=str(job.scene_path.resolve()),
        spec_sha256=file_sha256(job.scene_path),
        width=job.W,
        height=job.H,
        render=dataclasses.asdict(job.render),
        variant=pick_variant(),
        threads=threads,
    )
    scene = job.scene.name
    out = []
    for kind, fs in (("frames", frames), ("views", tests)):
        for chunk in frame_chunks(fs, frames_per_task):
            name = f"render:{scene}:{kind}:{chunk[0]}-{chunk[-1]}"
            out.append(RenderSpec(name=name, kind=kind, frames=chunk, **base))
    return out
