"""Mitsuba 3 rendering of benchgen scenes and exact pixel-centre ray casts (project issue 3,
"Rendering and exact ground truth"; docs/rendering.md).

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
import math
import os
import subprocess
import sys
from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Union

import numpy as np

from m4dgs.clip import TrackSet

from .denoise import denoise_hdr
from .groundtruth import DEFAULT_DEPTH_RTOL, RayCast, pixel_rays, render_noise

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
    the irradiance it gives the scene, :func:`emitter_sampling_weights`), "power-sqrt" (the square
    root of those weights, a compromise) or "auto" (whichever of the three is least noisy on the
    first frame, :func:`choose_emitter_sampling`); denoise: render the first-hit albedo and shading
    normal (Mitsuba's ``aov`` integrator, GUIDE_SPP samples) and denoise every frame with Open Image
    Denoise (:mod:`benchgen.denoise`)."""

    spp: int = 256
    max_depth: int = 2
    sampler: str = "ldsampler"
    rfilter: str = "box"
    seed: int = 0
    emitter_sampling: str = "uniform"
    denoise: bool = False

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


# Per-preset sampler settings (docs/rendering.md has the measurements behind them). max_depth 2 =
# direct light only (lamps, sun, environment): one indirect bounce (max_depth 3) doubled the
# two-seed noise term of HDR-TAE at equal spp and made shadowed pixels (lit only indirectly) flicker
# by ~100 % from frame to frame. The low-discrepancy sampler ("ldsampler") halved the noise of
# "multijitter" at 64 spp on a small-lamp scene (216x120).
RENDER_PRESETS: Dict[str, RenderSettings] = {
    "tiny": RenderSettings(
        spp=64, max_depth=2, sampler="ldsampler", emitter_sampling="auto", denoise=True
    ),
    # 64 spp meets the 15-minute target for the small suite on 2 cores (256 took ~37 min); the
    # per-clip light selection lowers its noise by up to 2x and the denoiser by a further ~3x
    # (docs/rendering.md). ldsampler rounds spp to a power of 4: the next step up is 256 (`benchgen
    # make --spp 256`).
    "small": RenderSettings(
        spp=64, max_depth=2, sampler="ldsampler", emitter_sampling="auto", denoise=True
    ),
    "paper": RenderSettings(
        spp=1024, max_depth=2, sampler="ldsampler", emitter_sampling="auto", denoise=True
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


def emitter_sampling_weights(fs, min_weight: float = 1e-3) -> Dict[str, float]:
    """Light-selection weights for next-event estimation, proportional to each emitter's irradiance
    on the scene.

    Mitsuba picks the light of a shadow-ray sample with probability proportional to its
    `sampling_weight` (all 1 by default). In these scenes a small lamp of radiance ~5000 sits next
    to an environment of ~0.005, so uniform selection spends most shadow rays on a light that BSDF
    sampling (MIS) already handles well and leaves the lamp undersampled. Irradiance estimates at
    the scene's typical distance d (the median camera-z of the non-emitter vertices in the frame-0
    camera, >= 0.1):

    - area emitter (one-sided mesh, total area A, mean radiance L): L * (A / 4) / d^2  (projected
      area of a closed convex emitter is A / 4; a flat panel is within a factor of 2 of it);
    - constant environment of radiance L: pi * L;  sun: its irradiance.

    Args:
        fs: benchgen.scene.FrameState of frame 0. min_weight: floor relative to the largest weight,
        so that every light keeps some shadow rays.
    Returns:
        {"env": w, "sun": w (if present), mesh name: w for each emitter mesh}, largest weight 1.
    """
    w2c = np.linalg.inv(np.asarray(fs.c2w, np.float64))
    zs = [
        ((np.asarray(m.vertices, np.float64) @ w2c[:3, :3].T) + w2c[:3, 3])[:, 2]
        for m in fs.meshes
        if m.material.kind != "emitter"
    ]
    z = np.concatenate(zs) if zs else np.zeros(0)
    z = z[z > 0]
    d = max(float(np.median(z)) if z.size else 1.0, 0.1)
    est: Dict[str, float] = {"env": math.pi * float(np.mean(fs.lighting.env_radiance))}
    lt = fs.lighting
    if lt.sun_direction is not None and lt.sun_irradiance is not None:
        est["sun"] = float(np.mean(lt.sun_irradiance))
    for m in fs.meshes:
        if m.material.kind == "emitter" and m.material.radiance is not None:
            V = np.asarray(m.vertices, np.float64)
            F = np.asarray(m.faces, np.int64)
            area = (
                0.5
                * np.linalg.norm(
                    np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1
                ).sum()
            )
            est[m.name] = float(np.mean(m.material.radiance)) * area / 4.0 / d**2
    top = max(est.values())
    if top <= 0:
        return {k: 1.0 for k in est}
    return {k: max(v / top, min_weight) for k, v in est.items()}


EMITTER_SAMPLING_MODES = ("uniform", "power", "power-sqrt")


def emitter_weights_for(mode: str, fs) -> Dict[str, float]:
    """Light-selection weights of an emitter_sampling mode ({} = Mitsuba's uniform default)."""
    if mode == "uniform":
        return {}
    if mode == "power":
        return emitter_sampling_weights(fs)
    if mode == "power-sqrt":
        return {k: math.sqrt(v) for k, v in emitter_sampling_weights(fs).items()}
    raise ValueError(
        f"emitter_sampling must be one of {EMITTER_SAMPLING_MODES + ('auto',)}, got {mode!r}"
    )


EMITTER_PROBE_SPP = 16  # spp of choose_emitter_sampling's probe renders
GUIDE_SPP = 16  # spp of the albedo / normal guides of the denoiser (first hits only: cheap)


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

        denoise (default: settings.denoise): pass the frame through benchgen.denoise.denoise_hdr,
        guided by an albedo / normal render of GUIDE_SPP samples, with the emitter pixels of this
        state's ray cast."""
        mi = self._mi
        if seed is None:
            seed = self.settings.seed + int(self.state.g)
        img = np.array(
            mi.render(self.scene, seed=int(seed), spp=int(spp or self.settings.spp)),
            dtype=np.float32,
        )
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
        return denoise_hdr(color, aux[..., 0:3], aux[..., 3:6], self.emitter_pixels())

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
# Whole-clip ground truth
# --------------------------------------------------------------------------------------------------
# seed of the second, independent render of the first frame (noise measurement)
NOISE_SEED_OFFSET = 1_000_003


def render_clip_gt(
    scene,
    width: int,
    height: int,
    frames,
    preset,
    out,
    progress: bool = True,
    *,
    num_grid: int = 256,
    num_dynamic: int = 64,
    num_ref: int = 4,
    rtol: float = DEFAULT_DEPTH_RTOL,
    hdr_dir=("gt", "hdr"),
) -> dict:
    """Render and write the ground truth of a clip through a m4dgs.clip.ClipWriter.

    For every frame g in `frames`: the HDR frame into `hdr_dir` (a folder relative to the clip,
    default gt/hdr; skipped when the file exists: resume; read back where needed), gt/depth
    (z-depth, 0 = no surface) and gt/masks/dynamic. Then gt/cameras.json, gt/flow.npz (exact flow +
    visibility between consecutive TRAINING frames of out.meta.split.train, both directions) and
    gt/tracks.npz (over all frames, queries from `num_ref` reference frames). Returns the
    ground-truth notes, also merged into out.meta.gt: render_noise {rel_std, tae_two_seeds, mu_psnr}
    from two seeds of the first frame, hdr_tae_floor (HDR-TAE of the ground-truth training sequence
    with its exact flow and visibility), render settings, variant and timings. Does not call
    out.finalize() (the caller owns clip.json)."""
    import time

    from m4dgs.clip import FlowSet, frame_name
    from m4dgs.core import io as mio
    from m4dgs.core.temporal import depth_edges, hdr_tae_pairs, interior_visibility

    from .groundtruth import (
        SurfaceQueries,
        cameras_from_states,
        default_reference_indices,
        dynamic_mask,
        flow_between,
        render_noise,
        select_queries,
        track_frame,
    )

    settings = RenderSettings.resolve(preset)
    frames = [int(g) for g in frames]
    if not frames:
        raise ValueError("render_clip_gt: no frames")
    fset = set(frames)
    train = [g for g in out.meta.split.train if g in fset]

    first = scene.frame(frames[0], width, height)
    renderer = Renderer(first, width, height, settings)

    # pass 1: query points on the reference frames (ray casts only)
    rng = np.random.default_rng(settings.seed)
    refs = default_reference_indices(len(frames), num_ref)
    queries = []
    for r in refs:
        st = first if r == 0 else scene.frame(frames[r], width, height)
        renderer.update(st)
        queries.append(select_queries(renderer.cast_rays(), st, r, num_grid, num_dynamic, rng))
    q = SurfaceQueries.concat(queries)

    # pass 2: every frame
    iterator = frames
    if progress:
        try:
            from tqdm import tqdm

            iterator = tqdm(frames, desc=f"render {getattr(scene, 'name', '')}", unit="frame")
        except ImportError:
            pass
    cams, tr_uv, tr_p3, tr_vis = [], [], [], []
    pairs, flows, valids, tae_pairs, tae_inner = [], [], [], [], []
    prev = None  # (g, state, cast, hdr) of the previous training frame
    noise, noise_interior, surface_fraction = None, None, None
    t_render, t_cast, n_render = 0.0, 0.0, 0
    for g in iterator:
        st = first if g == frames[0] else scene.frame(g, width, height)
        renderer.update(st)
        t0 = time.perf_counter()
        cast = renderer.cast_rays()
        t_cast += time.perf_counter() - t0
        cams.append(st)
        hdr_rel = tuple(hdr_dir) + (frame_name(g, "exr"),)
        need_hdr = g in train or g == frames[0]
        hdr = None
        if out.exists(*hdr_rel):
            if need_hdr:
                hdr = mio.read_exr(out.root.joinpath(*hdr_rel)).astype(np.float32)
        else:
            t0 = time.perf_counter()
            hdr = renderer.render_hdr()
            t_render += time.perf_counter() - t0
            n_render += 1
            mio.write_exr(out.root.joinpath(*hdr_rel), hdr)
        if not out.exists("gt", "depth", frame_name(g, "exr")):
            out.write_gt_depth(g, cast.depth)
        if not out.exists("gt", "masks", "dynamic", frame_name(g, "png")):
            out.write_gt_dynamic_mask(g, dynamic_mask(cast.instance, st))
        if g == frames[0]:
            other = renderer.render_hdr(seed=settings.seed + g + NOISE_SEED_OFFSET)
            noise = render_noise(hdr, other, cast.hit)
            noise_interior = render_noise(hdr, other, cast.hit & ~depth_edges(cast.depth))
            surface_fraction = float(cast.hit.mean())
        uv, p3, vis = track_frame(q, st, cast.depth, cast.instance, rtol)
        tr_uv.append(uv)
        tr_p3.append(p3)
        tr_vis.append(vis)
        if g in train:
            if prev is not None:
                ga, sa, ca, ha = prev
                f_ab, v_ab = flow_between(
                    ca, st, st, cast.depth, cast.instance, cam_a=sa, rtol=rtol
                )
                f_ba, v_ba = flow_between(cast, sa, sa, ca.depth, ca.instance, cam_a=st, rtol=rtol)
                pairs += [(ga, g), (g, ga)]
                flows += [f_ab, f_ba]
                valids += [v_ab, v_ba]
                tae_pairs += hdr_tae_pairs(
                    np.stack([ha, hdr]), f_ab[None], f_ba[None], v_ab[None], v_ba[None]
                )
                ea, eb = depth_edges(ca.depth), depth_edges(cast.depth)
                tae_inner += hdr_tae_pairs(
                    np.stack([ha, hdr]),
                    f_ab[None],
                    f_ba[None],
                    interior_visibility(v_ab, f_ab, ea, eb)[None],
                    interior_visibility(v_ba, f_ba, eb, ea)[None],
                )
            prev = (g, st, cast, hdr)

    out.write_gt_cameras(cameras_from_states(cams))
    if pairs:
        out.write_gt_flow(
            FlowSet(pairs=np.array(pairs, np.int64), flow=np.stack(flows), valid=np.stack(valids))
        )
    ts = TrackSet(
        tracks=np.stack(tr_uv, 1).astype(np.float32),
        visible=np.stack(tr_vis, 1),
        frames=np.array(frames, np.int64),
        points3d=np.stack(tr_p3, 1).astype(np.float32),
        dynamic=q.dynamic.astype(bool),
    )
    out.write_gt_tracks(ts)

    finite = [v for v in tae_pairs if np.isfinite(v)]
    finite_inner = [v for v in tae_inner if np.isfinite(v)]
    notes = {
        "render": {
            "variant": renderer.variant,
            **dataclasses.asdict(settings),
            "integrator": "path",
            "pixel_filter": "box",
            "emitter_sampling": renderer.emitter_sampling,
            "emitter_weights": renderer.emitter_weights,
        },
        "render_noise": {k: (float(v) if np.isfinite(v) else None) for k, v in noise.items()},
        "render_noise_pixels": "surface pixels of the first frame (no-surface pixels excluded, as "
        "in HDR-TAE)",
        "surface_fraction_first_frame": surface_fraction,
        "hdr_tae_floor": float(np.mean(finite)) if finite else None,
        "hdr_tae_floor_convention": "HDR-TAE (channel sum) of the gt training sequence with exact "
        "gt flow and "
        "visibility (eval.metrics.temporal.hdr_tae_pairs)",
        # where the floor comes from: occlusion-edge pixels (mixed colours, one flow), noise (two
        # seeds of frame 0, no motion), and the rest (resampling of texture by the bilinear warp,
        # shading that changes with motion)
        "hdr_tae_floor_parts": {
            "interior": float(np.mean(finite_inner)) if finite_inner else None,
            "edges": (float(np.mean(finite)) - float(np.mean(finite_inner)))
            if finite and finite_inner
            else None,
            "noise_interior_two_seeds": float(noise_interior["tae_two_seeds"]),
            "rest_interior": (float(np.mean(finite_inner)) - float(noise_interior["tae_two_seeds"]))
            if finite_inner
            else None,
        },
        "depth_no_surface": 0.0,
        "visibility_depth_rtol": rtol,
        "tracks": {
            "num": int(len(q)),
            "reference_frames": [frames[r] for r in refs],
            "num_grid": num_grid,
            "num_dynamic": num_dynamic,
        },
        "timing_s_per_frame": {
            "render": t_render / n_render if n_render else None,
            "ray_cast": t_cast / len(frames),
        },
    }
    out.meta.gt.update(notes)
    return notes
