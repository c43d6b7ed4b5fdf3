"""Declarative scene and suite specs: schema, validation, defaults (docs/scenes.md).

A scene spec is a YAML mapping validated against :data:`SCENE_SCHEMA`; a suite file against
:data:`SUITE_SCHEMA`. Validation fills in every default, rejects unknown keys and raises
:class:`SpecError` naming the file, the key path (``objects[2].motion.type``) and what was expected.
The schema is data: :func:`schema_markdown` prints the key reference of ``docs/scenes.md`` from it,
so the documentation cannot drift from the validator.

World conventions: right-handed, z up, metres, seconds, angles in degrees in specs. Radiance and
irradiance are linear."""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path
from typing import Any, List, Mapping, Optional, Sequence

import yaml

from benchgen.exposure import SCHEDULES
from m4dgs.core.checks import is_integer, is_number, unknown_keys
from m4dgs.core.errors import InputError
from m4dgs.core.io import YAMLSyntaxError, parse_yaml

_REQUIRED = object()


class SpecError(InputError):
    """A spec that does not validate. ``str(err)`` is ``"<file>: <key path>: expected <...>, got
    <...>"``."""

    def __init__(self, file, key_path: str, expected: str, got: Any = _REQUIRED):
        self.file = str(file)
        self.key_path = key_path or "<root>"
        self.expected = expected
        msg = f"{self.file}: {self.key_path}: expected {expected}"
        if got is not _REQUIRED:
            msg += f", got {_short(got)}"
        super().__init__(msg)


class _Raw(str):
    """A 'got' text printed as is (not repr'd)."""


def _short(v: Any) -> str:
    if isinstance(v, _Raw):
        return str(v)
    s = repr(v)
    return s if len(s) <= 80 else s[:77] + "..."


# --------------------------------------------------------------------------------------------------
# Schema nodes
# --------------------------------------------------------------------------------------------------
class Node:
    """Base schema node: ``check(value, file, path) -> normalised value``."""

    doc: str = ""

    def check(self, v, file, path):  # any value
        return v

    def describe(self) -> str:  # type name for docs and error messages
        return "value"


class Num(Node):
    def __init__(self, lo=None, hi=None, *, integer=False, lo_open=False, doc=""):
        self.lo, self.hi, self.integer, self.lo_open, self.doc = lo, hi, integer, lo_open, doc

    def describe(self):
        t = "int" if self.integer else "number"
        rng = []
        if self.lo is not None:
            rng.append(f"{'>' if self.lo_open else '>='} {self.lo:g}")
        if self.hi is not None:
            rng.append(f"<= {self.hi:g}")
        return t + (" " + " and ".join(rng) if rng else "")

    def check(self, v, file, path):
        if self.integer:
            if not is_integer(v):
                raise SpecError(file, path, self.describe(), v)
        elif not is_number(v, finite=True):
            raise SpecError(file, path, self.describe(), v)
        if self.lo is not None and (v < self.lo or (self.lo_open and v == self.lo)):
            raise SpecError(file, path, self.describe(), v)
        if self.hi is not None and v > self.hi:
            raise SpecError(file, path, self.describe(), v)
        return int(v) if self.integer else float(v)


class Str(Node):
    def __init__(self, enum: Optional[Sequence[str]] = None, allow_empty=False, doc=""):
        self.enum, self.allow_empty, self.doc = list(enum) if enum else None, allow_empty, doc

    def describe(self):
        return f"one of {self.enum}" if self.enum else "string"

    def check(self, v, file, path):
        if not isinstance(v, str) or (self.enum is not None and v not in self.enum):
            raise SpecError(file, path, self.describe(), v)
        if self.enum is None and not v and not self.allow_empty:
            raise SpecError(file, path, "non-empty string", v)
        return v


class Bool(Node):
    def __init__(self, doc=""):
        self.doc = doc

    def describe(self):
        return "bool"

    def check(self, v, file, path):
        if not isinstance(v, bool):
            raise SpecError(file, path, "bool (true/false)", v)
        return v


class Vec(Node):
    """Fixed-length list of numbers; a scalar is broadcast when ``broadcast`` is set (e.g. ``scale:
    2``)."""

    def __init__(
        self,
        n: int,
        lo=None,
        hi=None,
        *,
        integer=False,
        lo_open=False,
        nonzero=False,
        broadcast=False,
        doc="",
    ):
        self.n, self.nonzero, self.broadcast, self.doc = n, nonzero, broadcast, doc
        self.item = Num(lo, hi, integer=integer, lo_open=lo_open)

    def describe(self):
        item = self.item.describe().replace("number", "numbers").replace("int", "ints", 1)
        s = f"list of {self.n} {item}"
        if self.nonzero:
            s += ", not all zero"
        if self.broadcast:
            s += " (or one number)"
        return s

    def check(self, v, file, path):
        if self.broadcast and is_number(v, finite=True):
            v = [v] * self.n
        if not isinstance(v, (list, tuple)) or len(v) != self.n:
            raise SpecError(file, path, self.describe(), v)
        out = [self.item.check(x, file, f"{path}[{i}]") for i, x in enumerate(v)]
        if self.nonzero and all(x == 0 for x in out):
            raise SpecError(file, path, self.describe(), v)
        return out


class Optional_(Node):
    """``null`` or the inner node."""

    def __init__(self, inner: Node, doc=""):
        self.inner, self.doc = inner, doc or inner.doc

    def describe(self):
        return f"null or {self.inner.describe()}"

    def check(self, v, file, path):
        return None if v is None else self.inner.check(v, file, path)


class ListOf(Node):
    def __init__(self, item: Node, min_len: int = 0, max_len: Optional[int] = None, doc=""):
        self.item, self.min_len, self.max_len, self.doc = item, min_len, max_len, doc

    def describe(self):
        n = f"at least {self.min_len} " if self.min_len else ""
        if self.max_len is not None:
            n = f"{self.min_len}-{self.max_len} "
        inner = self.item.describe() if not isinstance(self.item, (Dict, Union)) else "mappings"
        return f"list of {n}{inner}"

    def check(self, v, file, path):
        if not isinstance(v, list):
            raise SpecError(file, path, self.describe(), v)
        if len(v) < self.min_len or (self.max_len is not None and len(v) > self.max_len):
            raise SpecError(file, path, self.describe(), _Raw(f"a list of length {len(v)}"))
        return [self.item.check(x, file, f"{path}[{i}]") for i, x in enumerate(v)]


@dataclass
class F:
    """One key of a mapping: schema node, default (``_REQUIRED`` when required) and meaning."""

    node: Node
    default: Any = _REQUIRED
    doc: str = ""


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


class Dict(Node):
    def __init__(self, fields: Mapping[str, F], doc: str = "", name: str = ""):
        self.fields, self.doc, self.name = fields, doc, name

    def describe(self):
        return "mapping"

    def check(self, v, file, path):
        if not isinstance(v, dict):
            raise SpecError(file, path, f"a mapping with keys {sorted(self.fields)}", v)
        bad = unknown_keys(v, self.fields)
        if bad:
            raise SpecError(
                file,
                _join(path, str(bad[0])),
                f"a known key (allowed here: {sorted(self.fields)})",
                _Raw("an unknown key"),
            )
        out = {}
        for k, f in self.fields.items():
            p = _join(path, k)
            if k in v:
                out[k] = f.node.check(v[k], file, p)
            elif f.default is _REQUIRED:
                raise SpecError(
                    file, p, f"a value for this required key ({f.node.describe()})", _Raw("nothing")
                )
            else:
                d = copy.deepcopy(f.default)
                out[k] = f.node.check(d, file, p) if d is not None else None
        return out


class Union(Node):
    """A mapping whose ``<tag>`` key (e.g. ``type``) selects one of several :class:`Dict`
    variants."""

    def __init__(self, tag: str, variants: Mapping[str, "Dict"], doc: str = ""):
        self.tag, self.variants, self.doc = tag, variants, doc

    def describe(self):
        return f"mapping with '{self.tag}' in {list(self.variants)}"

    def check(self, v, file, path):
        if not isinstance(v, dict):
            raise SpecError(file, path, self.describe(), v)
        if self.tag not in v:
            raise SpecError(
                file,
                _join(path, self.tag),
                f"a value for this required key (one of {list(self.variants)})",
                _Raw("nothing"),
            )
        t = v[self.tag]
        if not isinstance(t, str) or t not in self.variants:
            raise SpecError(file, _join(path, self.tag), f"one of {list(self.variants)}", t)
        rest = {k: x for k, x in v.items() if k != self.tag}
        out = self.variants[t].check(rest, file, path)
        return {self.tag: t, **out}


# --------------------------------------------------------------------------------------------------
# Scene schema
# --------------------------------------------------------------------------------------------------
RGB01 = Vec(3, 0.0, 1.0)
# physically plausible magnitudes: the scenes are rooms, courtyards and streets (the built-in ones
# stay within 25 m of the origin and their lamps below 1e4 in linear radiance); a value far outside
# is a typo (1e30 for 1.3) that would render black frames or overflow the HDR range
MAX_LENGTH_M = 1_000.0
MAX_RADIANCE = 1e6
RGB_POS = Vec(3, 0.0, MAX_RADIANCE)
COORD = Vec(3, -MAX_LENGTH_M, MAX_LENGTH_M)  # a position in metres

TEXTURE = Dict(
    {
        "type": F(
            Str(["checker", "stripes", "noise"]),
            _REQUIRED,
            "pattern: checker board, stripes or multi-octave value noise",
        ),
        "colors": F(
            ListOf(RGB01, 2, 2),
            [[0.8, 0.8, 0.8], [0.15, 0.15, 0.15]],
            "the two linear albedos the pattern blends between",
        ),
        "frequency": F(
            Num(0, None, lo_open=True),
            8.0,
            "cells (checker), stripe periods (stripes) or base lattice cells (noise) across the "
            "texture",
        ),
        "angle_deg": F(Num(), 0.0, "stripes: direction of the stripes in uv space"),
        "octaves": F(Num(1, 8, integer=True), 4, "noise: number of octaves"),
        "persistence": F(Num(0, 1), 0.5, "noise: amplitude ratio between successive octaves"),
        "noise_amount": F(
            Num(0, 1),
            0.0,
            "combination: strength of a multiplicative value-noise overlay on checker/stripes",
        ),
        "resolution": F(Num(8, 2048, integer=True), 256, "texture size in pixels (square)"),
        "seed": F(
            Optional_(Num(0, None, integer=True)),
            None,
            "noise seed; null derives it from the scene seed and the object index",
        ),
    },
    doc="Procedural texture (benchgen.textures); albedo values are clipped to [0.02, 0.95].",
    name="texture",
)

_SURFACE = {
    "color": F(RGB01, [0.5, 0.5, 0.5], "linear albedo when no texture is given"),
    "texture": F(Optional_(TEXTURE), None, "procedural albedo texture (overrides color)"),
}
MATERIAL = Union(
    "kind",
    {
        "diffuse": Dict(dict(_SURFACE), doc="Lambertian."),
        "glossy": Dict(
            {**_SURFACE, "roughness": F(Num(0.01, 1.0), 0.2, "GGX alpha")},
            doc="Rough conductor/plastic-like glossy surface.",
        ),
        "emitter": Dict(
            {
                "radiance": F(
                    RGB_POS,
                    _REQUIRED,
                    "area-light radiance (linear); lamps ~1e3-1e4, windows/sky ~10-50",
                )
            },
            doc="Area emitter on the mesh's front faces.",
        ),
    },
    doc="Material, selected by 'kind'.",
)

MESH = Union(
    "type",
    {
        "plane": Dict(
            {
                "size": F(
                    Vec(2, 0, MAX_LENGTH_M, lo_open=True),
                    _REQUIRED,
                    "extent along local x and y (centred, normal +z)",
                ),
                "subdivisions": F(Num(1, 256, integer=True), 4, "quads per side"),
            },
            doc="Rectangle in the local xy plane, normal +z.",
        ),
        "box": Dict(
            {
                "size": F(
                    Vec(3, 0, MAX_LENGTH_M, lo_open=True),
                    _REQUIRED,
                    "extent along local x, y, z (centred)",
                )
            },
            doc="Axis-aligned box.",
        ),
        "uv_sphere": Dict(
            {
                "radius": F(Num(0, MAX_LENGTH_M, lo_open=True), _REQUIRED, "radius"),
                "segments": F(Num(3, 512, integer=True), 32, "longitudinal segments"),
                "rings": F(Num(2, 256, integer=True), 16, "latitudinal rings"),
            },
            doc="UV sphere centred at the origin, poles on local z.",
        ),
        "cylinder": Dict(
            {
                "radius": F(Num(0, MAX_LENGTH_M, lo_open=True), _REQUIRED, "radius"),
                "height": F(Num(0, MAX_LENGTH_M, lo_open=True), _REQUIRED, "extent along local z"),
                "segments": F(Num(3, 512, integer=True), 24, "segments around the axis"),
                "caps": F(Bool(), True, "close both ends"),
                "origin": F(
                    Str(["center", "base"]),
                    "center",
                    "local origin at the centre or at the bottom cap",
                ),
            },
            doc="Cylinder along local z (thin ones make poles and wires).",
        ),
        "grid": Dict(
            {
                "size": F(
                    Vec(2, 0, MAX_LENGTH_M, lo_open=True),
                    _REQUIRED,
                    "extent along local x (away from the pole) and y",
                ),
                "resolution": F(Vec(2, 1, 1024, integer=True), [32, 16], "quads along x and y"),
            },
            doc="Subdivided sheet for cloth/flags: x in [0, w] (x = 0 is the pole edge), y in [0, "
            "h], normal +z.",
        ),
        "wall": Dict(
            {
                "size": F(
                    Vec(2, 0, MAX_LENGTH_M, lo_open=True),
                    _REQUIRED,
                    "width (local x, centred) and height (local z, from 0)",
                ),
                "thickness": F(
                    Num(0, MAX_LENGTH_M, lo_open=True), 0.1, "extent along local y (centred)"
                ),
                "opening": F(
                    Optional_(Vec(4)),
                    None,
                    "window (or door, z0 = 0) hole [x0, z0, x1, z1] in wall coordinates, or null",
                ),
            },
            doc="Upright wall in the local xz plane, optionally with a rectangular window opening "
            "(built from boxes).",
        ),
        "chain": Dict(
            {
                "links": F(
                    ListOf(
                        Dict(
                            {
                                "shape": F(Str(["box", "cylinder"]), "box", "link geometry"),
                                "length": F(
                                    Num(0, MAX_LENGTH_M, lo_open=True),
                                    _REQUIRED,
                                    "extent along the link's local z",
                                ),
                                "width": F(
                                    Num(0, MAX_LENGTH_M, lo_open=True),
                                    0.1,
                                    "box: side of the square cross-section",
                                ),
                                "radius": F(
                                    Num(0, MAX_LENGTH_M, lo_open=True), 0.05, "cylinder: radius"
                                ),
                            }
                        ),
                        1,
                    ),
                    _REQUIRED,
                    "links from the base to the tip; link i starts at joint i and extends along +z",
                ),
                "segments": F(Num(3, 256, integer=True), 16, "segments of cylinder links"),
            },
            doc="Articulated chain: links joined end to end by revolute joints (pose set by an "
            "'articulated' motion).",
        ),
    },
    doc="Procedural mesh, selected by 'type' (benchgen.meshes).",
)

_PIVOT = F(
    Optional_(Vec(3)),
    None,
    "world point the rotation axis passes through; null = the object's transform.translate",
)
MOTION = Union(
    "type",
    {
        "none": Dict({}, doc="Static object."),
        "keyframes": Dict(
            {
                "keys": F(
                    ListOf(
                        Dict(
                            {
                                "time": F(Num(0, None), _REQUIRED, "seconds"),
                                "position": F(COORD, _REQUIRED, "translation at that time"),
                                "rotate_deg": F(
                                    Vec(3),
                                    [0.0, 0.0, 0.0],
                                    "XYZ Euler rotation (R = Rz Ry Rx) at that time",
                                ),
                            }
                        ),
                        2,
                    ),
                    _REQUIRED,
                    "keyframes, strictly increasing in time; the pose is held outside their range",
                ),
                "interpolation": F(
                    Str(["catmull_rom", "linear"]),
                    "catmull_rom",
                    "C1 Catmull-Rom (positions) + normalised quaternion Hermite spline, or "
                    "piecewise lerp/slerp",
                ),
            },
            doc="Keyframed rigid motion: world = K(t) * transform (K = keyframe translation and "
            "rotation).",
        ),
        "translate": Dict(
            {
                "velocity": F(Vec(3, -MAX_LENGTH_M, MAX_LENGTH_M), _REQUIRED, "metres per second"),
                "start_time": F(Num(0, None), 0.0, "seconds before which the object rests"),
                "end_time": F(
                    Optional_(Num(0, None)),
                    None,
                    "seconds after which it rests again (null: never)",
                ),
            },
            doc="Constant-velocity translation.",
        ),
        "rotate": Dict(
            {
                "axis": F(Vec(3, nonzero=True), _REQUIRED, "world rotation axis direction"),
                "speed_deg_s": F(Num(), _REQUIRED, "angular speed (degrees per second)"),
                "pivot": _PIVOT,
            },
            doc="Constant-speed rotation about a world axis.",
        ),
        "oscillate": Dict(
            {
                "mode": F(
                    Str(["translate", "rotate"]),
                    "translate",
                    "oscillate along the axis or swing about it (pendulum)",
                ),
                "axis": F(
                    Vec(3, nonzero=True),
                    _REQUIRED,
                    "world direction (translate) or rotation axis (rotate)",
                ),
                "amplitude": F(Num(), _REQUIRED, "metres (translate) or degrees (rotate)"),
                "frequency_hz": F(Num(0, None), _REQUIRED, "oscillation frequency"),
                "phase_deg": F(Num(), 0.0, "phase offset"),
                "pivot": _PIVOT,
            },
            doc="Sinusoidal oscillation: offset = amplitude * sin(2 pi f t + phase).",
        ),
        "articulated": Dict(
            {
                "joints": F(
                    ListOf(
                        Dict(
                            {
                                "axis": F(
                                    Vec(3, nonzero=True),
                                    _REQUIRED,
                                    "joint axis in the parent link's frame",
                                ),
                                "base_deg": F(Num(), 0.0, "rest angle"),
                                "rate_deg_s": F(
                                    Num(), 0.0, "constant angular rate added to the rest angle"
                                ),
                                "amplitude_deg": F(Num(), 0.0, "sinusoidal swing amplitude"),
                                "frequency_hz": F(Num(0, None), 0.0, "sinusoidal swing frequency"),
                                "phase_deg": F(Num(), 0.0, "sinusoidal swing phase"),
                            }
                        ),
                        1,
                    ),
                    _REQUIRED,
                    "one joint per chain link: angle(t) = base + rate t + amplitude sin(2 pi f t "
                    "+ phase)",
                ),
            },
            doc="Forward kinematics of a 'chain' mesh.",
        ),
        "flag": Dict(
            {
                "amplitude": F(
                    Num(0, None),
                    0.1,
                    "wave amplitude at the free edge (metres, along the sheet normal)",
                ),
                "wavelength": F(Num(0, MAX_LENGTH_M, lo_open=True), 1.0, "metres along the sheet"),
                "frequency_hz": F(Num(0, None), 1.0, "wave frequency (travels away from the pole)"),
                "growth": F(
                    Num(0, None, lo_open=True),
                    1.5,
                    "amplitude grows as (x / width) ** growth from the pole",
                ),
                "sag": F(
                    Num(0, None),
                    0.0,
                    "extra droop of the free edge (metres, along -y of the sheet)",
                ),
            },
            doc="Non-rigid waving flag on a 'grid' mesh: travelling sine wave, pole edge (x = 0) "
            "fixed.",
        ),
    },
    doc="Object motion, selected by 'type' (benchgen.motion).",
)

TRANSFORM = Dict(
    {
        "translate": F(COORD, [0.0, 0.0, 0.0], "world position of the local origin"),
        "rotate_deg": F(Vec(3), [0.0, 0.0, 0.0], "XYZ Euler angles, R = Rz Ry Rx"),
        "scale": F(
            Vec(3, 0, None, lo_open=True, broadcast=True),
            [1.0, 1.0, 1.0],
            "per-axis scale (or one number)",
        ),
    },
    doc="Static placement: world = T(translate) R(rotate) S(scale) * local.",
)

OBJECT = Dict(
    {
        "name": F(Str(), _REQUIRED, "unique object name"),
        "mesh": F(MESH, _REQUIRED, "geometry"),
        "material": F(MATERIAL, {"kind": "diffuse"}, "appearance"),
        "transform": F(TRANSFORM, {}, "static placement"),
        "motion": F(MOTION, {"type": "none"}, "object motion over time"),
    },
    doc="One object = one mesh with one material and one motion.",
)

_JITTER = Dict(
    {
        "position_m": F(Num(0, None), 0.01, "standard deviation of the positional jitter"),
        "rotation_deg": F(
            Num(0, None), 0.3, "standard deviation of the rotational jitter (per axis)"
        ),
        "frequency_hz": F(
            Num(0, None, lo_open=True), 1.5, "highest frequency of the smooth jitter"
        ),
        "seed": F(Optional_(Num(0, None, integer=True)), None, "null: the scene seed"),
    },
    doc="Smooth hand-shake: sums of seeded sinusoids (band-limited, not white noise).",
)
TRAJECTORY = Union(
    "type",
    {
        "static": Dict(
            {
                "position": F(COORD, _REQUIRED, "camera centre"),
                "target": F(COORD, _REQUIRED, "look-at point"),
                "roll_deg": F(Num(), 0.0, "roll about the optical axis"),
            },
            doc="Fixed camera.",
        ),
        "orbit": Dict(
            {
                "target": F(COORD, _REQUIRED, "orbit centre and look-at point"),
                "radius": F(
                    Num(0, MAX_LENGTH_M, lo_open=True),
                    _REQUIRED,
                    "horizontal distance to the target",
                ),
                "height": F(
                    Num(-MAX_LENGTH_M, MAX_LENGTH_M), 1.0, "camera height above the target"
                ),
                "start_deg": F(
                    Num(), 0.0, "azimuth at t = 0 (0 = +x, counter-clockwise seen from above)"
                ),
                "sweep_deg": F(
                    Num(), 90.0, "azimuth swept over the whole clip (num_frames / fps seconds)"
                ),
                "roll_deg": F(Num(), 0.0, "roll about the optical axis"),
            },
            doc="Constant-speed circular orbit looking at the target (distance to the target is "
            "constant).",
        ),
        "dolly": Dict(
            {
                "start": F(COORD, _REQUIRED, "camera centre at t = 0"),
                "end": F(COORD, _REQUIRED, "camera centre at the last frame"),
                "target": F(COORD, _REQUIRED, "look-at point"),
                "track_target": F(
                    Bool(),
                    False,
                    "false: orientation fixed (looking at the target from 'start'); true: keep "
                    "looking at the target",
                ),
                "ease": F(
                    Bool(), True, "smooth ease-in/ease-out along the rail (else constant speed)"
                ),
            },
            doc="Straight rail move.",
        ),
        "handheld": Dict(
            {
                "waypoints": F(
                    ListOf(COORD, 2),
                    _REQUIRED,
                    "camera centres, passed through at evenly spaced times (Catmull-Rom)",
                ),
                "targets": F(
                    ListOf(COORD, 1),
                    _REQUIRED,
                    "look-at points, evenly spaced in time (one = fixed target)",
                ),
                "jitter": F(_JITTER, {}, "hand shake"),
            },
            doc="Smooth hand-held path with small smooth jitter.",
        ),
    },
    doc="Camera trajectory, selected by 'type'.",
)

VIEW = Dict(
    {
        "name": F(Str(), _REQUIRED, "view name (folder gt/views/<name>/)"),
        "orbit_deg": F(
            Vec(2, -89.0, 89.0),
            [0.0, 0.0],
            "[yaw, pitch]: the camera swung about the look-at point, about the test camera's up "
            "axis (yaw, positive to the camera's right) then its right axis (pitch, positive up)",
        ),
        "offset": F(
            Vec(3, -2.0, 2.0),
            [0.0, 0.0, 0.0],
            "[right, up, forward] translation after the swing, in units of the distance to the "
            "look-at point, orientation kept",
        ),
    },
    doc="A held-out viewpoint, placed relative to each test frame's camera and its look-at point "
    "(the point on the optical axis at the median depth of the frame's central pixels).",
)

#: the held-out views of a scene without its own: three baselines off the input path
DEFAULT_VIEWS = [
    {"name": "small", "orbit_deg": [0.0, 6.0], "offset": [0.0, 0.0, 0.0]},
    {"name": "medium", "orbit_deg": [0.0, 0.0], "offset": [0.25, 0.0, 0.15]},
    {"name": "large", "orbit_deg": [-25.0, 10.0], "offset": [0.0, 0.0, 0.0]},
]

CAMERA = Dict(
    {
        "fov_deg": F(Num(5, 170), 60.0, "horizontal field of view"),
        "trajectory": F(TRAJECTORY, _REQUIRED, "camera path"),
        "views": F(
            ListOf(VIEW, 0, 8),
            DEFAULT_VIEWS,
            "held-out viewpoints of every test frame (ground truth only; [] renders none)",
        ),
    },
    doc="Pinhole camera; intrinsics come from fov_deg and the rendered width/height.",
)

LIGHTING = Dict(
    {
        "environment": F(RGB_POS, [0.01, 0.01, 0.01], "constant environment radiance (dim)"),
        "sun": F(
            Optional_(
                Dict(
                    {
                        "direction": F(
                            Vec(3, nonzero=True),
                            _REQUIRED,
                            "from the scene towards the sun (normalised on load)",
                        ),
                        "irradiance": F(
                            RGB_POS, _REQUIRED, "irradiance on a surface facing the sun"
                        ),
                    }
                )
            ),
            None,
            "directional sun, or null",
        ),
    },
    doc="Global lighting (lamps and windows are emitter objects).",
)

SCENE_SCHEMA = Dict(
    {
        "name": F(Str(), _REQUIRED, "scene name (clip folder name)"),
        "description": F(Str(allow_empty=True), "", "one line"),
        "fps": F(Num(0, None, lo_open=True), 30.0, "frames per second; frame g is at time g / fps"),
        "num_frames": F(Num(2, 100000, integer=True), 100, "global frames G (a preset may cap it)"),
        "seed": F(Num(0, None, integer=True), 0, "seed for textures and jitter"),
        "camera": F(CAMERA, _REQUIRED, "camera"),
        "lighting": F(LIGHTING, {}, "lighting"),
        "objects": F(ListOf(OBJECT, 1), _REQUIRED, "objects (instance ids 1.. in this order)"),
    },
    doc="A scene spec (one YAML file per scene).",
)

SUITE_SCHEMA = Dict(
    {
        "name": F(Str(), _REQUIRED, "suite name"),
        "description": F(Str(allow_empty=True), "", "one line"),
        "scenes": F(
            ListOf(Str(), 1),
            _REQUIRED,
            "scene names (scenes/<name>.yaml) or paths relative to the suite file",
        ),
        "exposures": F(
            Dict(
                {
                    "observed": F(
                        ListOf(Num(0, None, lo_open=True), 1),
                        _REQUIRED,
                        "exposure times of the training frames (cycled)",
                    ),
                    "novel": F(
                        ListOf(Num(0, None, lo_open=True)),
                        [],
                        "extra exposure times rendered for test frames only",
                    ),
                    "schedule": F(
                        Str(list(SCHEDULES)),
                        "alternating",
                        "how observed levels are assigned to training frames",
                    ),
                }
            ),
            _REQUIRED,
            "exposure settings",
        ),
        "placement": F(
            Str(["require", "warn"]),
            "require",
            "exposure-placement targets (docs/exposure.md): `require` fails `benchgen make` on a "
            "clip that "
            "misses one, `warn` only warns (smoke-test suites)",
        ),
    },
    doc="A suite file: scenes + exposure settings.",
)


# --------------------------------------------------------------------------------------------------
# Entry points
# --------------------------------------------------------------------------------------------------
def read_yaml(path) -> Any:
    """Parse a YAML file; a syntax error becomes a SpecError naming the file."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise SpecError(path, "<file>", "a readable YAML file", _Raw(str(e))) from None
    try:
        return parse_yaml(text, str(path))
    except YAMLSyntaxError as e:
        raise SpecError(path, e.where or "<file>", "valid YAML", _Raw(e.what)) from None


def validate_scene(data: Any, file="<spec>") -> dict:
    """Validated scene spec with all defaults filled in (plain nested dicts/lists). Raises
    SpecError."""
    spec = SCENE_SCHEMA.check(data, file, "")
    names = {}
    for i, obj in enumerate(spec["objects"]):
        p = f"objects[{i}]"
        if obj["name"] in names:
            raise SpecError(
                file,
                f"{p}.name",
                f"a unique name (already used by objects[{names[obj['name']]}])",
                obj["name"],
            )
        names[obj["name"]] = i
        mesh, motion = obj["mesh"], obj["motion"]
        if motion["type"] == "articulated":
            if mesh["type"] != "chain":
                raise SpecError(
                    file,
                    f"{p}.mesh.type",
                    "'chain' (required by motion.type 'articulated')",
                    mesh["type"],
                )
            if len(motion["joints"]) != len(mesh["links"]):
                raise SpecError(
                    file,
                    f"{p}.motion.joints",
                    f"one joint per chain link ({len(mesh['links'])})",
                    _Raw(f"{len(motion['joints'])} joints"),
                )
        elif mesh["type"] == "chain":
            raise SpecError(
                file,
                f"{p}.motion.type",
                "'articulated' (a 'chain' mesh needs joint angles)",
                motion["type"],
            )
        if motion["type"] == "flag" and mesh["type"] != "grid":
            raise SpecError(
                file, f"{p}.mesh.type", "'grid' (required by motion.type 'flag')", mesh["type"]
            )
        if motion["type"] == "keyframes":
            times = [k["time"] for k in motion["keys"]]
            for j in range(1, len(times)):
                if times[j] <= times[j - 1]:
                    raise SpecError(
                        file,
                        f"{p}.motion.keys[{j}].time",
                        f"a time > {times[j - 1]:g} (strictly increasing)",
                        times[j],
                    )
                r0, r1 = motion["keys"][j - 1]["rotate_deg"], motion["keys"][j]["rotate_deg"]
                if max(abs(a - b) for a, b in zip(r0, r1)) >= 180:
                    raise SpecError(
                        file,
                        f"{p}.motion.keys[{j}].rotate_deg",
                        f"angles within 180 degrees of the previous key's {r0} (rotations are "
                        "interpolated "
                        "along the shortest arc: add keys for larger turns)",
                        r1,
                    )
        if (
            motion["type"] == "translate"
            and motion["end_time"] is not None
            and motion["end_time"] < motion["start_time"]
        ):
            raise SpecError(
                file,
                f"{p}.motion.end_time",
                f"null or >= start_time ({motion['start_time']:g})",
                motion["end_time"],
            )
        if mesh["type"] == "wall" and mesh["opening"] is not None:
            w, h = mesh["size"]
            x0, z0, x1, z1 = mesh["opening"]
            if not (-w / 2 < x0 < x1 < w / 2 and 0 <= z0 < z1 < h):
                raise SpecError(
                    file,
                    f"{p}.mesh.opening",
                    f"-{w / 2:g} < x0 < x1 < {w / 2:g} and 0 <= z0 < z1 < {h:g}",
                    mesh["opening"],
                )
    traj = spec["camera"]["trajectory"]
    if traj["type"] in ("static",) and traj["position"] == traj["target"]:
        raise SpecError(
            file,
            "camera.trajectory.target",
            "a point different from the camera position",
            traj["target"],
        )
    names = [v["name"] for v in spec["camera"]["views"]]
    for i, n in enumerate(names):
        if n in names[:i] or "/" in n or n.startswith("."):
            raise SpecError(
                file, f"camera.views[{i}].name", "a unique folder name (no '/', no leading '.')", n
            )
    return spec


def load_scene_spec(path) -> dict:
    """Read and validate a scene YAML file."""
    return validate_scene(read_yaml(path), file=str(path))


def validate_suite(data: Any, file="<suite>") -> dict:
    """Validated suite spec with defaults filled in. Raises SpecError."""
    return SUITE_SCHEMA.check(data, file, "")


# --------------------------------------------------------------------------------------------------
# Documentation from the schema
# --------------------------------------------------------------------------------------------------
def _fmt_default(d) -> str:
    if d is _REQUIRED:
        return "**required**"
    # one line (a table cell): no wrapping of long defaults
    text = yaml.safe_dump(d, default_flow_style=True, width=float("inf"))
    return "`" + text.strip().removesuffix("...").strip() + "`"


def _doc_rows(node: Node, path: str, rows: List[str]):
    if isinstance(node, Optional_):
        node = node.inner
    if isinstance(node, ListOf) and isinstance(node.item, (Dict, Union)):
        _doc_rows(node.item, path + "[i]", rows)
        return
    if isinstance(node, Union):
        for name, var in node.variants.items():
            rows.append(f"| `{path}.{node.tag}: {name}` | | | {var.doc} |")
            _doc_rows(var, path, rows)
        return
    if isinstance(node, Dict):
        for k, f in node.fields.items():
            p = _join(path, k)
            rows.append(f"| `{p}` | {f.node.describe()} | {_fmt_default(f.default)} | {f.doc} |")
            _doc_rows(f.node, p, rows)


def schema_markdown(schema: Node = SCENE_SCHEMA) -> str:
    """Markdown table of every key: path, type, default, meaning."""
    rows = ["| key | type | default | meaning |", "|---|---|---|---|"]
    _doc_rows(schema, "", rows)
    return "\n".join(rows).replace("`.", "`")


if __name__ == "__main__":  # python -m benchgen.spec  -> key reference tables
    print(
        "## Scene keys\n\n"
        + schema_markdown(SCENE_SCHEMA)
        + "\n\n## Suite keys\n\n"
        + schema_markdown(SUITE_SCHEMA)
    )
