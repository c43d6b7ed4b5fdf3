"""Mitsuba 3 rendering of benchgen scenes and exact pixel-centre ray casts (docs/rendering.md).

This module holds the renderer: the render presets (:class:`RenderSettings`), the Mitsuba variant,
the sensor conventions, :class:`Renderer` (one scene per clip, animated in place, HDR renders and
exact ray casts) and :func:`choose_emitter_sampling`, which renders probes with it to resolve a
preset's "auto" light selection. The sampling maths it applies (light-selection weights, the
adaptive sampler's allocation) is in benchgen.sampling; the pass over a clip's frames that makes its
ground truth is in benchgen.clip_pass.

- Variant: ``llvm_ad_rgb`` when it works (needs Debian ``libllvm19``; drjit is pointed at it through
  ``DRJIT_LIBLLVM_PATH``), else ``scalar_rgb``. :func:`pick_variant` chooses once per process (a
  throw-away subprocess probes the LLVM variant, because a broken LLVM aborts the process instead of
  raising); the environment variable ``BENCHGEN_MI_VARIANT`` overrides the choice.
- One Mitsuba scene is built from the first :class:`benchgen.scene.FrameState`;
  :meth:`Renderer.update` moves every mesh's ``vertex_positions``, the sensor and the lights in
  place through ``mi.traverse`` (no reload).
- Camera: the FrameState camera is OpenCV (x right, y down, z forward, c2w). Mitsuba's perspective
  camera looks down its local +z with local x pointing image-LEFT and y image-UP, so
  ``sensor.to_world = c2w @ diag(-1, -1, 1, 1)``; ``x_fov = 2 atan(W / (2 fx))``; the principal
  point offset (fraction of the film, measured with ``sensor.sample_ray``) is ``((W/2 - cx) / W,
  (H/2 - cy) / H)``. Square pixels only (fx == fy).
- Radiance: linear RGB, path tracer, box pixel filter (each pixel is the mean over its footprint),
  sampler / spp / max_depth from :data:`RENDER_PRESETS`.
- Ground truth never comes from AOVs: :meth:`Renderer.cast_rays` traces one ray through each exact
  pixel centre (u = i + 0.5) with ``scene.ray_intersect``, identifies the hit mesh by object
  identity (``si.shape`` compared with each mesh's pointer; ``shape_index`` differs between
  variants), and recomputes the hit in float64 from the hit triangle's vertices (Moller-Trumbore),
  which gives the barycentrics and the z-depth exactly.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Union

import numpy as np

from .denoise import denoise_hdr
from .groundtruth import RayCast, pixel_rays, render_noise
from .sampling import (
    ADAPTIVE_BLOCK_SPP,
    EMITTER_SAMPLING_MODES,
    adaptive_allocation,
    emitter_weights_for,
    relative_variance,
)

DEFAULT_LIBLLVM = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
LLVM_VARIANT = "llvm_ad_rgb"
SCALAR_VARIANT = "scalar_rgb"

_CHOSEN_VARIANT: Optional[str] = None  # process-wide: mitsuba's variant is a process-global setting


# --------------------------------------------------------------------------------------------------
# Settings
# --------------------------------------------------------------------------------------------------
@dataclass
class RenderSettings:
    """Path-tracer settings of one preset (docs/rendering.md has the measured noise and HDR-TAE
    floors).

    spp: samples per pixel; max_depth: path length (2 = direct light only, 3 = one indirect bounce);
    sampler: Mitsuba sampler plugin ("ldsampler" low-discrepancy and "multijitter" stratify the
    pixel footprint and the light samples and lower the noise at equal spp; "independent" is plain
    Monte Carlo); seed: base seed, frame g is rendered with seed + g so that a resumed render is
    bit-identical; emitter_sampling: how next-event estimation picks a light: "uniform" (Mitsuba's
    default, every emitter equally often), "power" (each emitter's `sampling_weight` proportional to
    the irradiance it gives the scene, :func:`benchgen.sampling.emitter_sampling_weights`),
    "power-sqrt" (the square root of those weights, a compromise) or "auto" (whichever of the three
    is least noisy on the first frame, :func:`choose_emitter_sampling`); denoise: render the
    first-hit albedo and shading normal (Mitsuba's ``aov`` integrator, GUIDE_SPP samples) and
    denoise every frame with Open Image Denoise (:mod:`benchgen.denoise`); adaptive_spp: average
    number of extra samples per pixel that :meth:`Renderer.render_hdr` spends, in blocks of
    ADAPTIVE_BLOCK_SPP, on the pixels whose relative Monte Carlo variance is highest (0 = every
    pixel gets spp samples; :func:`benchgen.sampling.adaptive_allocation`); denoise_ladder: denoise
    as an exposure ladder of OIDN passes (:func:`benchgen.denoise.denoise_hdr`, generator version 6)
    instead of one pass at OIDN's automatic exposure."""

    spp: int = 256
    max_depth: int = 2
    sampler: str = "ldsampler"
    rfilter: str = "box"
    seed: int = 0
    emitter_sampling: str = "uniform"
    denoise: bool = False
    adaptive_spp: int = 0
    denoise_ladder: bool = True

    @staticmethod
    def resolve(preset: Union[str, "RenderSettings", Dict[str, Any], None]) -> "RenderSettings":
        """A RenderSettings from a preset name, a dict of fields, or a RenderSettings (returned as
        is)."""
        if preset is None:
            return RenderSettings()
        if isinstance(preset, RenderSettings):
            return preset
        if isinstance(preset, str):
            if preset not in RENDER_PRESETS:
                raise ValueError(
                    f"unknown render preset {preset!r} (known: {sorted(RENDER_PRESETS)})"
                )
            return dataclasses.replace(RENDER_PRESETS[preset])
        if isinstance(preset, dict):
            known = {f.name for f in dataclasses.fields(RenderSettings)}
            bad = sorted(set(preset) - known)
            if bad:
                raise ValueError(f"unknown render setting(s) {bad} (known: {sorted(known)})")
            return RenderSettings(**preset)
        raise TypeError(
            f"render preset must be a name, dict or RenderSettings, got {type(preset).__name__}"
        )


#: extra samples per pixel (mean) of the adaptive sampler at the tiny and small presets: +25 % of
#: the samples; measured two-seed noise (interior, frame 0, small) at +0 / +16 / +32 / +64:
#: conveyor-occlusion-orbit 0.078 / 0.063 / 0.062 / 0.056, drone-window-handheld 0.076 / 0.071 /
#: 0.069 / 0.064, lamp-room-orbit 0.036 / 0.032 / 0.031 / 0.031
ADAPTIVE_SPP = 16

# Per-preset sampler settings (docs/rendering.md has the measurements behind them). max_depth 2 =
# direct light only (lamps, sun, environment): one indirect bounce (max_depth 3) doubled the
# two-seed noise term of HDR-TAE at equal spp and made shadowed pixels (lit only indirectly) flicker
# by ~100 % from frame to frame. The low-discrepancy sampler ("ldsampler") halved the noise of
# "multijitter" at 64 spp on a small-lamp scene (216x120).
RENDER_PRESETS: Dict[str, RenderSettings] = {
    "tiny": RenderSettings(
        spp=64,
        max_depth=2,
        sampler="ldsampler",
        emitter_sampling="auto",
        denoise=True,
        adaptive_spp=ADAPTIVE_SPP,
    ),
    # 64 spp with the adaptive samples keeps the small suite within the 15-minute target on 2 cores
    # (256 took ~37 min; the whole suite measured on an idle machine: docs/rendering.md). The
    # per-clip light selection lowers its noise by up to 2x and the denoiser by a further ~3x, the
    # adaptive samples (+25 % of the samples, where the relative variance is highest) by a further
    # 5-20 %. ldsampler rounds spp to a power of 4: the next step up is 256
    # (`benchgen make --spp 256`).
    "small": RenderSettings(
        spp=64,
        max_depth=2,
        sampler="ldsampler",
        emitter_sampling="auto",
        denoise=True,
        adaptive_spp=ADAPTIVE_SPP,
    ),
    "paper": RenderSettings(
        spp=1024,
        max_depth=2,
        sampler="ldsampler",
        emitter_sampling="auto",
        denoise=True,
        adaptive_spp=16 * ADAPTIVE_SPP,
    ),
}


# --------------------------------------------------------------------------------------------------
# Variant
# --------------------------------------------------------------------------------------------------
_PROBE = (
    "import mitsuba as mi\n"
    "mi.set_variant('{v}')\n"
    "s = mi.load_dict({{'type': 'scene', 'integrator': {{'type': 'path', 'max_depth': 3}},"
    " 'sensor': {{'type': 'perspective', 'film': {{'type': 'hdrfilm', 'width': 8, 'height': 8}}}},"
    " 'sh': {{'type': 'sphere', 'center': [0, 0, 4]}}, 'env': {{'type': 'constant'}}}})\n"
    "import numpy as np\n"
    "img = np.array(mi.render(s, spp=4))\n"
    "assert np.isfinite(img).all() and img.mean() > 0\n"
    "print('ok')\n"
)


def _llvm_works(timeout_s: float = 180.0) -> bool:
    """Render a tiny scene with the LLVM variant in a subprocess (a broken LLVM aborts the
    interpreter)."""
    try:
        r = subprocess.run(
            [sys.executable, "-c", _PROBE.format(v=LLVM_VARIANT)],
            capture_output=True,
            text=True,
            timeout=timeout_s,
            env=dict(os.environ),
        )
    except (subprocess.TimeoutExpired, OSError):
        return False
    return r.returncode == 0 and "ok" in r.stdout


def pick_variant() -> str:
    """Select (once per process) and activate the Mitsuba variant; returns its name.

    ``BENCHGEN_MI_VARIANT`` forces a variant. Otherwise ``llvm_ad_rgb`` if a probe render succeeds
    (with ``DRJIT_LIBLLVM_PATH`` set to libLLVM 19 when unset and present), else ``scalar_rgb``."""
    global _CHOSEN_VARIANT
    import mitsuba as mi

    if _CHOSEN_VARIANT is not None:
        if mi.variant() != _CHOSEN_VARIANT:
            mi.set_variant(_CHOSEN_VARIANT)
        return _CHOSEN_VARIANT
    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(DEFAULT_LIBLLVM):
        os.environ["DRJIT_LIBLLVM_PATH"] = DEFAULT_LIBLLVM
    forced = os.environ.get("BENCHGEN_MI_VARIANT")
    if forced:
        if forced not in mi.variants():
            raise ValueError(
                f"BENCHGEN_MI_VARIANT={forced!r} is not an installed variant {mi.variants()}"
            )
        variant = forced
    elif LLVM_VARIANT in mi.variants() and _llvm_works():
        variant = LLVM_VARIANT
    else:
        variant = SCALAR_VARIANT
    mi.set_variant(variant)
    _CHOSEN_VARIANT = variant
    return variant


def use_variant(variant: str) -> str:
    """Render with `variant` in this process from now on (a render task takes the variant its
    driver picked, so that a worker never probes and picks another); raises InputError naming it
    when this machine's Mitsuba does not have it."""
    global _CHOSEN_VARIANT
    import mitsuba as mi

    from m4dgs.core.errors import InputError

    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(DEFAULT_LIBLLVM):
        os.environ["DRJIT_LIBLLVM_PATH"] = DEFAULT_LIBLLVM
    if variant not in mi.variants():
        raise InputError(
            f"the Mitsuba variant {variant!r} the clip is rendered with is not installed on this "
            f"worker (it has {', '.join(mi.variants())})"
        )
    if mi.variant() != variant:
        mi.set_variant(variant)
    _CHOSEN_VARIANT = variant
    return variant


def renderer_info() -> dict:
    """{"mitsuba", "drjit", "oidn", "variant"}: the package versions the renders and the denoiser
    come from, and the Mitsuba variant this process picked (None when it rendered nothing, e.g. a
    clip whose renders were all resumed or reused). Clip.json records it with the host
    (m4dgs.core.host): the LLVM variant and the denoiser pick kernels for the host CPU, so a clip
    regenerated on another machine can differ in its last digits (docs/reliability.md)."""
    from importlib import metadata

    def version(pkg):
        try:
            return metadata.version(pkg)
        except metadata.PackageNotFoundError:
            return None

    return {
        "mitsuba": version("mitsuba"),
        "drjit": version("drjit"),
        "oidn": version("pyoidn"),
        "variant": _CHOSEN_VARIANT,
    }


# --------------------------------------------------------------------------------------------------
# Camera conversion
# --------------------------------------------------------------------------------------------------
OPENCV_TO_MITSUBA_CAMERA = np.diag([-1.0, -1.0, 1.0, 1.0])


def sensor_to_world(c2w: np.ndarray) -> np.ndarray:
    """Mitsuba sensor to_world [4, 4] from an OpenCV c2w [4, 4] (Mitsuba camera: x image-left, y
    image-up)."""
    return np.asarray(c2w, np.float64) @ OPENCV_TO_MITSUBA_CAMERA


def sensor_intrinsics(K: np.ndarray, width: int, height: int) -> Dict[str, float]:
    """Mitsuba perspective parameters {x_fov (deg), ppo_x, ppo_y} equivalent to the OpenCV K (square
    pixels)."""
    K = np.asarray(K, np.float64)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if abs(fx - fy) > 1e-6 * fx or abs(K[0, 1]) > 1e-9:
        raise ValueError(
            f"Mitsuba's perspective camera needs square pixels and no skew, got K={K.tolist()}"
        )
    return {
        "x_fov": float(np.degrees(2.0 * np.arctan(width / (2.0 * fx)))),
        "ppo_x": float((width / 2.0 - cx) / width),
        "ppo_y": float((height / 2.0 - cy) / height),
    }


# --------------------------------------------------------------------------------------------------
# Renderer
# --------------------------------------------------------------------------------------------------
def _mesh_id(i: int, name: str) -> str:
    safe = "".join(c if c.isalnum() or c == "_" else "_" for c in name)
    return f"m{i:03d}_{safe}"


EMITTER_PROBE_SPP = 16  # spp of choose_emitter_sampling's probe renders
GUIDE_SPP = 16  # spp of the albedo / normal guides of the denoiser (first hits only: cheap)
#: lanes (pixels x samples) of one Mitsuba launch of the adaptive sampler
MAX_LANES_PER_LAUNCH = 1 << 22


def _mix_seed(*parts: int) -> int:
    """A 32-bit sampler seed from integers (splitmix-style mixing; deterministic)."""
    x = 0x9E3779B97F4A7C15
    for p in parts:
        x = (x ^ (int(p) & 0xFFFFFFFFFFFFFFFF)) * 0xBF58476D1CE4E5B9 & 0xFFFFFFFFFFFFFFFF
        x ^= x >> 31
    return int(x & 0xFFFFFFFF)


class Renderer:
    """One Mitsuba scene for a whole clip; `update` animates it in place.

    Args:
        frame_state0: benchgen.scene.FrameState of the first frame (fixes meshes, topology,
        materials, lights). width, height: image size in pixels.
        preset_settings: preset name ("tiny" | "small" | "paper"), dict of RenderSettings fields, or
        RenderSettings.
    """

    def __init__(self, frame_state0, width: int, height: int, preset_settings=None):
        self.variant = pick_variant()
        import mitsuba as mi

        self._mi = mi
        self.width, self.height = int(width), int(height)
        self.settings = RenderSettings.resolve(preset_settings)
        self.mesh_ids: List[str] = [_mesh_id(i, m.name) for i, m in enumerate(frame_state0.meshes)]
        self._names = [m.name for m in frame_state0.meshes]
        self._has_sun = (
            frame_state0.lighting.sun_direction is not None
            and frame_state0.lighting.sun_irradiance is not None
        )
        mode = self.settings.emitter_sampling
        if mode == "auto":
            mode, _ = choose_emitter_sampling(frame_state0, width, height, self.settings)
        self.emitter_sampling = mode
        self.emitter_weights = emitter_weights_for(mode, frame_state0)
        self.scene = mi.load_dict(self._scene_dict(frame_state0))
        self.params = mi.traverse(self.scene)
        # object identity of the meshes inside the scene (never shape_index: it differs between
        # variants)
        by_id = {s.id(): s for s in self.scene.shapes()}
        self._shapes = [by_id[mid] for mid in self.mesh_ids]
        self.state = frame_state0
        self.num_updates = 0
        self._guides = (
            None  # Mitsuba aov integrator for the denoiser's albedo / normal, loaded on first use
        )
        self.last_extra_spp: Optional[float] = None  # adaptive samples of the last render_hdr
        self._samplers: Dict[int, Any] = {}  # pixel_sums' samplers by spp

    # -- scene construction
    # ------------------------------------------------------------------------------------
    def _texture(self, material):
        mi = self._mi
        if material.albedo is not None:
            alb = np.ascontiguousarray(np.clip(np.asarray(material.albedo, np.float32), 0.0, 1.0))
            if alb.ndim != 3 or alb.shape[2] != 3:
                raise ValueError(f"albedo texture must be [h, w, 3], got {alb.shape}")
            return {
                "type": "bitmap",
                "bitmap": mi.Bitmap(alb),
                "raw": True,
                "filter_type": "bilinear",
                "wrap_mode": "repeat",
            }
        return {"type": "rgb", "value": [float(c) for c in material.color]}

    def _bsdf(self, material):
        mi = self._mi
        kind = material.kind
        if kind == "diffuse":
            inner = {"type": "diffuse", "reflectance": self._texture(material)}
        elif kind == "glossy":
            inner = {
                "type": "roughplastic",
                "distribution": "ggx",
                "alpha": float(material.roughness),
                "diffuse_reflectance": self._texture(material),
            }
        elif kind == "emitter":
            inner = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}
        else:
            raise ValueError(f"unknown material kind {kind!r} (diffuse | glossy | emitter)")
        return (
            mi.load_dict({"type": "twosided", "bsdf": inner})
            if kind != "emitter"
            else mi.load_dict(inner)
        )

    def _mesh(self, i: int, ms):
        mi = self._mi
        props = mi.Properties()
        props["bsdf"] = self._bsdf(ms.material)
        if ms.material.kind == "emitter":
            if ms.material.radiance is None:
                raise ValueError(f"mesh {ms.name!r}: emitter material without radiance")
            props["emitter"] = mi.load_dict(
                {
                    "type": "area",
                    "radiance": {"type": "rgb", "value": [float(c) for c in ms.material.radiance]},
                    "sampling_weight": float(self.emitter_weights.get(ms.name, 1.0)),
                }
            )
        V = np.asarray(ms.vertices, np.float64)
        Fc = np.asarray(ms.faces, np.int64)
        uv = np.asarray(ms.uvs, np.float32)
        if (
            V.ndim != 2
            or V.shape[1] != 3
            or Fc.ndim != 2
            or Fc.shape[1] != 3
            or uv.shape != (V.shape[0], 2)
        ):
            raise ValueError(
                f"mesh {ms.name!r}: bad shapes vertices {V.shape}, faces {Fc.shape}, uvs {uv.shape}"
            )
        mesh = mi.Mesh(
            self.mesh_ids[i],
            vertex_count=V.shape[0],
            face_count=Fc.shape[0],
            has_vertex_texcoords=True,
            props=props,
        )
        p = mi.traverse(mesh)
        p["vertex_positions"] = type(p["vertex_positions"])(
            np.ascontiguousarray(V.astype(np.float32).ravel())
        )
        p["faces"] = type(p["faces"])(np.ascontiguousarray(Fc.astype(np.uint32).ravel()))
        p["vertex_texcoords"] = type(p["vertex_texcoords"])(np.ascontiguousarray(uv.ravel()))
        p.update()
        return mesh

    def _sensor(self, fs) -> dict:
        mi = self._mi
        intr = sensor_intrinsics(fs.K, self.width, self.height)
        s = self.settings
        return {
            "type": "perspective",
            "fov_axis": "x",
            "fov": intr["x_fov"],
            "principal_point_offset_x": intr["ppo_x"],
            "principal_point_offset_y": intr["ppo_y"],
            "near_clip": 1e-3,
            "far_clip": 1e5,
            "to_world": mi.ScalarTransform4f(sensor_to_world(fs.c2w).tolist()),
            "film": {
                "type": "hdrfilm",
                "width": self.width,
                "height": self.height,
                "pixel_format": "rgb",
                "component_format": "float32",
                "rfilter": {"type": s.rfilter},
            },
            "sampler": {"type": s.sampler, "sample_count": int(s.spp)},
        }

    def _sun_to_world(self, direction):
        """to_world of a directional emitter whose light travels along -direction (direction points
        to the sun)."""
        mi = self._mi
        d = -np.asarray(direction, np.float64)
        d = d / np.linalg.norm(d)
        up = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        return mi.ScalarTransform4f().look_at(
            origin=[0.0, 0.0, 0.0], target=d.tolist(), up=up.tolist()
        )

    def _scene_dict(self, fs) -> dict:
        d: Dict[str, Any] = {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": int(self.settings.max_depth)},
            "sensor": self._sensor(fs),
            "env": {
                "type": "constant",
                "radiance": {"type": "rgb", "value": [float(c) for c in fs.lighting.env_radiance]},
                "sampling_weight": float(self.emitter_weights.get("env", 1.0)),
            },
        }
        if self._has_sun:
            d["sun"] = {
                "type": "directional",
                "to_world": self._sun_to_world(fs.lighting.sun_direction),
                "irradiance": {
                    "type": "rgb",
                    "value": [float(c) for c in fs.lighting.sun_irradiance],
                },
                "sampling_weight": float(self.emitter_weights.get("sun", 1.0)),
            }
        for i, ms in enumerate(fs.meshes):
            d[self.mesh_ids[i]] = self._mesh(i, ms)
        return d

    # -- animation
    # ----------------------------------------------------------------------------------------------
    def update(self, frame_state) -> None:
        """Move vertices, sensor and lights to `frame_state` in place (mi.traverse + params.update,
        no reload)."""
        names = [m.name for m in frame_state.meshes]
        if names != self._names:
            raise ValueError(
                f"frame {frame_state.g}: meshes {names} differ from the first frame's {self._names}"
            )
        p = self.params
        for i, ms in enumerate(frame_state.meshes):
            key = f"{self.mesh_ids[i]}.vertex_positions"
            V = np.asarray(ms.vertices, np.float32)
            if V.shape != (len(p[key]) // 3, 3):
                raise ValueError(
                    f"frame {frame_state.g}: mesh {ms.name!r} vertex count changed to {V.shape}"
                )
            p[key] = type(p[key])(np.ascontiguousarray(V.ravel()))
        intr = sensor_intrinsics(frame_state.K, self.width, self.height)
        p["sensor.to_world"] = type(p["sensor.to_world"])(sensor_to_world(frame_state.c2w).tolist())
        p["sensor.x_fov"] = type(p["sensor.x_fov"])(intr["x_fov"])
        p["sensor.principal_point_offset_x"] = type(p["sensor.principal_point_offset_x"])(
            intr["ppo_x"]
        )
        p["sensor.principal_point_offset_y"] = type(p["sensor.principal_point_offset_y"])(
            intr["ppo_y"]
        )
        lt = frame_state.lighting
        p["env.radiance.value"] = type(p["env.radiance.value"])([float(c) for c in lt.env_radiance])
        if self._has_sun:
            if lt.sun_direction is None or lt.sun_irradiance is None:
                raise ValueError(
                    f"frame {frame_state.g}: the sun cannot be switched off (it exists in frame 0)"
                )
            p["sun.irradiance.value"] = type(p["sun.irradiance.value"])(
                [float(c) for c in lt.sun_irradiance]
            )
            p["sun.to_world"] = type(p["sun.to_world"])(self._sun_to_world(lt.sun_direction))
        p.update()
        self.state = frame_state
        self.num_updates += 1

    # -- rendering
    # ----------------------------------------------------------------------------------------------
    def render_hdr(
        self, seed: Optional[int] = None, spp: Optional[int] = None, denoise: Optional[bool] = None
    ) -> np.ndarray:
        """[H, W, 3] float32 linear radiance of the current state (seed defaults to settings.seed +
        g).

        With settings.adaptive_spp > 0 the frame is rendered by :meth:`render_adaptive` (spp samples
        everywhere plus adaptive_spp per pixel on average where the relative variance is highest;
        the mean extra spp actually spent is kept in last_extra_spp), else by mi.render.

        denoise (default: settings.denoise): pass the frame through benchgen.denoise.denoise_hdr,
        guided by an albedo / normal render of GUIDE_SPP samples, with the emitter pixels of this
        state's ray cast."""
        mi = self._mi
        if seed is None:
            seed = self.settings.seed + int(self.state.g)
        spp = int(spp or self.settings.spp)
        self.last_extra_spp = None
        if self.settings.adaptive_spp > 0:
            color, blocks = self.render_adaptive(int(seed), spp, self.settings.adaptive_spp)
            self.last_extra_spp = float(blocks.mean() * ADAPTIVE_BLOCK_SPP)
        else:
            img = np.array(mi.render(self.scene, seed=int(seed), spp=spp), dtype=np.float32)
            color = np.ascontiguousarray(img[..., :3])
        if not (self.settings.denoise if denoise is None else denoise):
            return color
        # the guides need few samples (first hits only: 16 spp cost ~4 % of a 64-spp colour render
        # at 216x120)
        if self._guides is None:
            self._guides = mi.load_dict({"type": "aov", "aovs": "albedo:albedo,nn:sh_normal"})
        aux = np.array(
            mi.render(self.scene, integrator=self._guides, seed=int(seed), spp=GUIDE_SPP),
            np.float32,
        )
        return denoise_hdr(
            color,
            aux[..., 0:3],
            aux[..., 3:6],
            self.emitter_pixels(),
            ladder=self.settings.denoise_ladder,
        )

    def pixel_sums(self, pixels: np.ndarray, spp: int, seed: int):
        """Sum and sum of squares [n, 3] float64 of `spp` path-traced samples of each pixel.

        pixels: [n] flat pixel indices (row-major, y * W + x; repeats allowed: each entry is a
        sample sequence of its own). The samples are what mi.render
        draws for the box pixel filter (position uniform in the pixel footprint, the preset's
        sampler with `spp` samples per pixel, the scene's integrator), launched in chunks of at
        most MAX_LANES_PER_LAUNCH lanes; chunk c is seeded with _mix_seed(seed, c)."""
        import drjit as dr

        mi = self._mi
        pix = np.ascontiguousarray(np.asarray(pixels, np.int64).ravel())
        n = pix.size
        s1 = np.zeros((n, 3), np.float64)
        s2 = np.zeros((n, 3), np.float64)
        if n == 0:
            return s1, s2
        spp = int(spp)
        sensor = self.scene.sensors()[0]
        integ = self.scene.integrator()
        W, H = self.width, self.height
        chunk = max(1, MAX_LANES_PER_LAUNCH // spp)
        for c, a in enumerate(range(0, n, chunk)):
            part = pix[a : a + chunk]
            m = part.size
            if spp not in self._samplers:
                self._samplers[spp] = mi.load_dict(
                    {"type": self.settings.sampler, "sample_count": spp}
                )
            sampler = self._samplers[spp]
            # lanes [pixel, sample]: the sampler's sample index is lane % spp (as in mi.render)
            sampler.set_samples_per_wavefront(spp)
            sampler.seed(_mix_seed(seed, c), m * spp)
            lane_pix = dr.gather(
                mi.UInt32,
                mi.UInt32(part.astype(np.uint32)),
                dr.arange(mi.UInt32, m * spp) // spp,
            )
            off = sampler.next_2d()  # box pixel filter: uniform over the footprint
            pos = mi.Point2f(
                (mi.Float(lane_pix % W) + off.x) / W, (mi.Float(lane_pix // W) + off.y) / H
            )
            ray, weight = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
            spec, _, _ = integ.sample(self.scene, sampler, ray, None, True)
            rgb = mi.Color3f(spec) * weight
            rgb = dr.select(dr.isfinite(rgb), rgb, 0.0)
            dr.eval(rgb)  # one path-tracing launch; the sums below only read it
            sums = [dr.block_sum(rgb[k], spp) for k in range(3)]
            sums += [dr.block_sum(rgb[k] * rgb[k], spp) for k in range(3)]
            dr.eval(*sums)
            for k in range(3):
                s1[a : a + m, k] = np.array(sums[k], np.float64)
                s2[a : a + m, k] = np.array(sums[3 + k], np.float64)
        return s1, s2

    def render_adaptive(self, seed: int, spp: int, extra_spp: float):
        """Adaptive render of the current state: (color [H, W, 3] float32, blocks [H, W] int).

        Every pixel gets `spp` samples (seed `seed`); their per-pixel variance gives the relative
        variance map (benchgen.sampling.relative_variance), adaptive_allocation spends
        extra_spp * pixels more samples in blocks of ADAPTIVE_BLOCK_SPP where they lower the sum of
        relative errors most (one launch, seed _mix_seed(seed, 1)), and each pixel is the mean of
        all its samples (a box filter over the footprint, as mi.render)."""
        H, W = self.height, self.width
        allp = np.arange(H * W)
        s1, s2 = self.pixel_sums(allp, spp, seed)
        mean = s1 / spp
        var = (s2 / spp - mean**2) * spp / max(spp - 1, 1)
        blocks = adaptive_allocation(
            relative_variance(mean.reshape(H, W, 3), var.reshape(H, W, 3)), spp, extra_spp
        )
        count = np.full(H * W, float(spp))
        flat = blocks.ravel()
        # every extra block is one sample sequence of its own (the sampler scrambles each group of
        # ADAPTIVE_BLOCK_SPP lanes independently), all in one launch
        groups = np.repeat(allp, flat)
        if groups.size:
            e1, _ = self.pixel_sums(groups, ADAPTIVE_BLOCK_SPP, _mix_seed(seed, 1))
            np.add.at(s1, groups, e1)
            count += flat * ADAPTIVE_BLOCK_SPP
        color = (s1 / count[:, None]).reshape(H, W, 3).astype(np.float32)
        return np.ascontiguousarray(color), blocks

    def emitter_pixels(self) -> np.ndarray:
        """[H, W] bool: pixels of the current state whose centre ray hits an emitter (cached per
        state)."""
        if getattr(self, "_emit_key", None) != (id(self.state), self.num_updates):
            self.cast_rays()  # caches the mask
        return self._emit_mask

    # -- exact ray casts
    # ------------------------------------------------------------------------------------------
    def _intersect(self, o: np.ndarray, d: np.ndarray):
        """Mitsuba first hits of rays o [N, 3], unit d [N, 3]: (mesh index [N] (-1 none), prim index
        [N])."""
        mi = self._mi
        n = o.shape[0]
        mesh = np.full(n, -1, np.int64)
        prim = np.full(n, -1, np.int64)
        if self.variant.startswith("scalar"):
            shapes = self._shapes
            for k in range(n):
                si = self.scene.ray_intersect(mi.Ray3f(o=o[k].tolist(), d=d[k].tolist()))
                if not si.is_valid():
                    continue
                for j, s in enumerate(shapes):
                    if si.shape == s:
                        mesh[k] = j
                        prim[k] = int(si.prim_index)
                        break
            return mesh, prim
        o32 = np.ascontiguousarray(o.astype(np.float32).T)
        d32 = np.ascontiguousarray(d.astype(np.float32).T)
        ray = mi.Ray3f(o=mi.Point3f(o32[0], o32[1], o32[2]), d=mi.Vector3f(d32[0], d32[1], d32[2]))
        si = self.scene.ray_intersect(ray)
        valid = np.array(si.is_valid(), dtype=bool)
        pidx = np.array(si.prim_index, dtype=np.int64)
        for j, s in enumerate(self._shapes):
            sel = np.array(si.shape == mi.ShapePtr(s), dtype=bool) & valid
            mesh[sel] = j
            prim[sel] = pidx[sel]
        return mesh, prim

    def cast_rays(self, frame_state=None) -> RayCast:
        """Exact per-pixel ground truth of the current state (or of `frame_state`, after `update` to
        it).

        One ray per exact pixel centre (u = i + 0.5, v = j + 0.5) of the OpenCV camera (K, c2w).
        Returns a benchgen.groundtruth.RayCast: z-depth (camera z of the hit, 0 where no surface),
        instance id (0 none), mesh index, triangle index and float64 barycentrics recomputed from
        the hit triangle's float64 vertices."""
        if frame_state is not None and frame_state is not self.state:
            self.update(frame_state)
        fs = self.state
        H, W = self.height, self.width
        # o [3], d [H*W, 3] with camera-z component 1
        o, d_cam_world = pixel_rays(fs.K, fs.c2w, W, H)
        dn = d_cam_world / np.linalg.norm(d_cam_world, axis=1, keepdims=True)
        orig = np.broadcast_to(o, dn.shape)
        mesh, prim = self._intersect(np.ascontiguousarray(orig), dn)
        # emitter pixels of this state, for the denoiser (no second ray cast when a frame is cast,
        # then rendered) mesh -1 -> the last entry
        kinds = np.array([m.material.kind == "emitter" for m in fs.meshes] + [False])
        self._emit_mask, self._emit_key = kinds[mesh.reshape(H, W)], (id(fs), self.num_updates)
        return _exact_hits(fs, o, d_cam_world, mesh, prim, H, W)


def _exact_hits(
    fs, o: np.ndarray, d: np.ndarray, mesh: np.ndarray, prim: np.ndarray, H: int, W: int
) -> RayCast:
    """float64 Moller-Trumbore on the hit triangles. d has camera-z 1, so the ray parameter t is the
    z-depth."""
    n = H * W
    depth = np.zeros(n, np.float64)
    bary = np.zeros((n, 3), np.float64)
    inst = np.zeros(n, np.int32)
    for j, ms in enumerate(fs.meshes):
        sel = np.nonzero(mesh == j)[0]
        if sel.size == 0:
            continue
        V = np.asarray(ms.vertices, np.float64)
        tri = np.asarray(ms.faces, np.int64)[prim[sel]]
        v0, v1, v2 = V[tri[:, 0]], V[tri[:, 1]], V[tri[:, 2]]
        e1, e2 = v1 - v0, v2 - v0
        dd = d[sel]
        pv = np.cross(dd, e2)
        det = np.einsum("ij,ij->i", e1, pv)
        det = np.where(np.abs(det) < 1e-300, 1e-300, det)
        tv = o[None, :] - v0
        b1 = np.einsum("ij,ij->i", tv, pv) / det
        qv = np.cross(tv, e1)
        b2 = np.einsum("ij,ij->i", dd, qv) / det
        t = np.einsum("ij,ij->i", e2, qv) / det
        depth[sel] = t
        bary[sel] = np.stack([1.0 - b1 - b2, b1, b2], axis=1)
        inst[sel] = int(ms.instance_id)
    hit = mesh >= 0
    return RayCast(
        depth=np.where(hit, depth, 0.0).astype(np.float32).reshape(H, W),
        instance=inst.reshape(H, W),
        mesh=mesh.astype(np.int32).reshape(H, W),
        triangle=np.where(hit, prim, -1).astype(np.int64).reshape(H, W),
        bary=bary.reshape(H, W, 3),
    )


# --------------------------------------------------------------------------------------------------
# Light selection of a clip: probe renders (a Renderer resolves a preset's "auto" with it)
# --------------------------------------------------------------------------------------------------
def choose_emitter_sampling(
    fs, width: int, height: int, settings, probe_spp: int = EMITTER_PROBE_SPP
):
    """The light-selection mode with the least Monte Carlo noise on frame state `fs`.

    Renders `fs` twice (two seeds) at `probe_spp` with each mode of EMITTER_SAMPLING_MODES and
    scores the pair by its HDR-TAE noise term over surface pixels
    (benchgen.groundtruth.render_noise), the quantity the ground truth's temporal floor is made of.
    Measured on the syn-exp-3 scenes: the 16-spp ranking predicts the 64-spp one; no single mode
    wins everywhere (irradiance weights halve the noise of a small-lamp room but raise it where a
    large window and a small lamp light different parts of the frame). Returns (mode, {mode:
    noise}); deterministic."""
    base = RenderSettings.resolve(settings)
    scores: Dict[str, float] = {}
    if (
        not any(m.material.kind == "emitter" for m in fs.meshes)
        and fs.lighting.sun_irradiance is None
    ):
        return "uniform", scores  # the environment is the only light: nothing to choose
    for mode in EMITTER_SAMPLING_MODES:
        r = Renderer(
            fs,
            width,
            height,
            dataclasses.replace(base, spp=int(probe_spp), emitter_sampling=mode, denoise=False),
        )
        hit = r.cast_rays().hit
        a = r.render_hdr(seed=base.seed + 1)
        b = r.render_hdr(seed=base.seed + 2)
        scores[mode] = float(render_noise(a, b, hit)["tae_two_seeds"])
    best = min(EMITTER_SAMPLING_MODES, key=lambda m: (scores[m], EMITTER_SAMPLING_MODES.index(m)))
    return best, scores
