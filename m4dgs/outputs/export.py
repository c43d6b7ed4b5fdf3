"""Export the Gaussians of a trained run at one time as a standard 3DGS .ply (opens in common splat
viewers).

The file is the layout written by the original 3D Gaussian Splatting code and read by the usual
viewers (SuperSplat,
antimatter15/splat, gsplat viewers, ...): one `vertex` element with 62 float32 properties, binary
little-endian::

    x y z                  world position nx ny nz               normals (unused; zeros) f_dc_0
    f_dc_1 f_dc_2   spherical-harmonics DC coefficient per channel: (rgb - 0.5) / C0, C0 =
    0.28209479177387814 f_rest_0 .. f_rest_44  higher SH coefficients of a degree-3 model (zeros:
    the colour is view-independent) opacity                logit of the opacity in (0, 1) scale_0
    scale_1 scale_2  log of the standard deviations along the Gaussian's local axes rot_0 rot_1
    rot_2 rot_3  unit rotation quaternion (w, x, y, z)

Mono4DGS-HDR Gaussians carry HDR irradiance, not LDR SH colour: `export_run_ply` bakes the learned
tone mapper into the colour at one exposure dt (default the unit exposure 1), rgb = phi(log2(H) +
log2 dt), so an LDR viewer shows the scene as the camera would have recorded it at that exposure.
Positions are in the run's estimated world frame (the first estimated camera's OpenCV axes as set by
camera initialisation: x right, y down, z forward; arbitrary scale); the header says so in a
`comment m4dgs ...` line."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
import torch

from m4dgs.core.errors import InputError
from m4dgs.core.io import atomic_target
from m4dgs.model.render import gaussian_colors
from m4dgs.model.trained import load_model

#: Y_0^0 = 1 / (2 sqrt(pi)); 3DGS colour = 0.5 + SH_C0 * f_dc (+ higher bands)
SH_C0 = 0.28209479177387814
#: number of f_rest coefficients of a degree-3 SH model (15 per channel, channel-major)
NUM_F_REST = 45
#: clamp used before the logit / log so that opacities 0 / 1 and scale 0 stay finite
_EPS = 1e-7

#: standard 3DGS vertex properties, in file order (all float32)
PLY_PROPERTIES: Tuple[str, ...] = (
    ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2")
    + tuple(f"f_rest_{i}" for i in range(NUM_F_REST))
    + ("opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")
)

#: numpy dtype of one vertex (little-endian float32 fields)
VERTEX_DTYPE = np.dtype([(name, "<f4") for name in PLY_PROPERTIES])

# PLY scalar type names -> numpy codes (both the classic and the sized spellings)
_PLY_TYPES: Dict[str, str] = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
_NUMPY_TO_PLY = {
    "i1": "char",
    "u1": "uchar",
    "i2": "short",
    "u2": "ushort",
    "i4": "int",
    "u4": "uint",
    "f4": "float",
    "f8": "double",
}


# --------------------------------------------------------------------------------------------------
# conversions
# --------------------------------------------------------------------------------------------------
def _np(x, name: str, shape_tail: Tuple[int, ...]) -> np.ndarray:
    a = (
        x.detach().cpu().double().numpy()
        if isinstance(x, torch.Tensor)
        else np.asarray(x, dtype=np.float64)
    )
    if a.ndim != 1 + len(shape_tail) or tuple(a.shape[1:]) != shape_tail:
        raise ValueError(
            f"gaussians_to_ply_arrays: '{name}' must have shape "
            f"[N{''.join(', %d' % s for s in shape_tail)}], "
            f"got {tuple(a.shape)}"
        )
    if not np.isfinite(a).all():
        raise ValueError(f"gaussians_to_ply_arrays: '{name}' contains NaN or inf")
    return a


def rgb_to_sh_dc(rgb: np.ndarray) -> np.ndarray:
    """LDR colour in [0, 1] -> degree-0 SH coefficient (viewers show 0.5 + SH_C0 * f_dc)."""
    return (np.asarray(rgb, np.float64) - 0.5) / SH_C0


def sh_dc_to_rgb(f_dc: np.ndarray) -> np.ndarray:
    """Inverse of `rgb_to_sh_dc`."""
    return 0.5 + SH_C0 * np.asarray(f_dc, np.float64)


def gaussians_to_ply_arrays(means, quats, scales, opacities, rgb) -> np.ndarray:
    """Standard 3DGS vertex records from activated Gaussian parameters.

    Args:
        means: [N, 3] world positions. quats: [N, 4] rotations (w, x, y, z), normalised here.
        scales: [N, 3] standard deviations (actual, > 0; written as log). opacities: [N] in (0, 1)
        (written as logit;
            clamped to [1e-7, 1 - 1e-7] first). rgb: [N, 3] LDR colour in [0, 1] (written as SH DC;
            clipped).
        Torch tensors or numpy arrays.
    Returns:
        numpy structured array [N] with dtype VERTEX_DTYPE (fields PLY_PROPERTIES, little-endian
        float32).
    """
    m = _np(means, "means", (3,))
    n = m.shape[0]
    q = _np(quats, "quats", (4,))
    s = _np(scales, "scales", (3,))
    o = _np(opacities, "opacities", ())
    c = _np(rgb, "rgb", (3,))
    for name, a in (("quats", q), ("scales", s), ("opacities", o), ("rgb", c)):
        if a.shape[0] != n:
            raise ValueError(
                f"gaussians_to_ply_arrays: '{name}' has {a.shape[0]} rows, means has {n}"
            )
    if (s <= 0).any():
        raise ValueError(
            "gaussians_to_ply_arrays: scales must be > 0 (pass actual scales, not log-scales)"
        )
    qn = np.linalg.norm(q, axis=1, keepdims=True)
    if (qn < 1e-12).any():
        raise ValueError("gaussians_to_ply_arrays: zero-length quaternion")
    q = q / qn
    o = np.clip(o, _EPS, 1.0 - _EPS)
    out = np.zeros(n, dtype=VERTEX_DTYPE)
    for i, k in enumerate("xyz"):
        out[k] = m[:, i]
    dc = rgb_to_sh_dc(np.clip(c, 0.0, 1.0))
    for i in range(3):
        out[f"f_dc_{i}"] = dc[:, i]
        out[f"scale_{i}"] = np.log(s[:, i])
    out["opacity"] = np.log(o) - np.log1p(-o)
    for i in range(4):
        out[f"rot_{i}"] = q[:, i]
    return out


def ply_arrays_to_gaussians(arr: np.ndarray) -> Dict[str, np.ndarray]:
    """Inverse of `gaussians_to_ply_arrays`: dict of means [N,3], quats [N,4] (wxyz), scales [N,3],
    opacities [N], rgb [N,3] (float64)."""
    # noqa: E731
    col = lambda names: np.stack([np.asarray(arr[k], np.float64) for k in names], axis=1)
    return {
        "means": col(("x", "y", "z")),
        "quats": col(("rot_0", "rot_1", "rot_2", "rot_3")),
        "scales": np.exp(col(("scale_0", "scale_1", "scale_2"))),
        "opacities": 1.0 / (1.0 + np.exp(-np.asarray(arr["opacity"], np.float64))),
        "rgb": sh_dc_to_rgb(col(("f_dc_0", "f_dc_1", "f_dc_2"))),
    }


# --------------------------------------------------------------------------------------------------
# PLY writer / reader
# --------------------------------------------------------------------------------------------------
def _ply_type(dt: np.dtype) -> str:
    code = dt.kind + str(dt.itemsize)
    if code not in _NUMPY_TO_PLY:
        raise ValueError(f"write_ply: field type {dt} has no PLY scalar type")
    return _NUMPY_TO_PLY[code]


def ply_header(arrays: np.ndarray, comments: Sequence[str] = ()) -> bytes:
    """ASCII header of a binary little-endian PLY with one `vertex` element whose properties are the
    fields of the structured array `arrays` (in order)."""
    lines = ["ply", "format binary_little_endian 1.0"]
    for c in comments:
        c = re.sub(r"\s+", " ", str(c)).strip()  # a comment is one line
        lines.append(f"comment {c}")
    lines.append(f"element vertex {arrays.shape[0]}")
    for name in arrays.dtype.names:
        lines.append(f"property {_ply_type(arrays.dtype[name])} {name}")
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii")


def write_ply(path, arrays: np.ndarray, comments: Sequence[str] = ()) -> Path:
    """Write a structured array [N] (e.g. from `gaussians_to_ply_arrays`) as a binary little-endian
    PLY `vertex` element, atomically (temporary file in the same folder, then os.replace). Returns
    the path."""
    arrays = np.asarray(arrays)
    if arrays.dtype.names is None or arrays.ndim != 1:
        raise ValueError("write_ply: expected a 1-d numpy structured array (one record per vertex)")
    le = np.dtype([(n, arrays.dtype[n].newbyteorder("<")) for n in arrays.dtype.names])
    body = np.ascontiguousarray(arrays.astype(le, copy=False))
    path = Path(path)
    with atomic_target(path, ".ply") as tmp:
        with open(tmp, "wb") as f:
            f.write(ply_header(body, comments))
            f.write(body.tobytes())
    return path


def read_ply_header(path) -> Dict[str, object]:
    """Parse a PLY header: {"format", "comments" [str], "elements" [(name, count, [(type, prop),
    ...])], "header_bytes" (offset of the body)}. List properties are rejected (not used by 3DGS
    files)."""
    path = Path(path)
    with open(path, "rb") as f:
        if f.readline().rstrip(b"\r\n") != b"ply":
            raise ValueError(f"{path}: not a PLY file (missing 'ply' magic)")
        fmt, comments, elements = None, [], []
        while True:
            raw = f.readline()
            if not raw:
                raise ValueError(f"{path}: PLY header has no 'end_header'")
            line = raw.decode("ascii", errors="replace").rstrip("\r\n")
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "end_header":
                break
            if parts[0] == "format":
                fmt = parts[1]
            elif parts[0] == "comment":
                comments.append(line[len("comment ") :])
            elif parts[0] == "obj_info":
                comments.append(line)
            elif parts[0] == "element":
                elements.append((parts[1], int(parts[2]), []))
            elif parts[0] == "property":
                if not elements:
                    raise ValueError(f"{path}: property before any element")
                if parts[1] == "list":
                    raise ValueError(f"{path}: list property '{parts[-1]}' is not supported")
                if parts[1] not in _PLY_TYPES:
                    raise ValueError(f"{path}: unknown property type '{parts[1]}'")
                elements[-1][2].append((parts[1], parts[2]))
            else:
                raise ValueError(f"{path}: unexpected header line {line!r}")
        offset = f.tell()
    if fmt not in ("binary_little_endian", "binary_big_endian", "ascii"):
        raise ValueError(f"{path}: unsupported PLY format {fmt!r}")
    return {"format": fmt, "comments": comments, "elements": elements, "header_bytes": offset}


def read_ply(path, element: str = "vertex") -> np.ndarray:
    """Read one element of a PLY (binary little/big-endian or ascii, scalar properties only) as a
    structured array with native-order fields named as in the file."""
    path = Path(path)
    h = read_ply_header(path)
    data = path.read_bytes()[h["header_bytes"] :]
    fmt = h["format"]
    offset = 0
    lines: Optional[List[str]] = data.decode("ascii").split("\n") if fmt == "ascii" else None
    row = 0
    for name, count, props in h["elements"]:
        order = ">" if fmt == "binary_big_endian" else "<"
        dt = np.dtype([(p, order + _PLY_TYPES[t]) for t, p in props])
        if fmt == "ascii":
            vals = [ln.split() for ln in lines[row : row + count]]
            arr = np.zeros(count, dtype=dt.newbyteorder("="))
            for j, (_t, p) in enumerate(props):
                arr[p] = [v[j] for v in vals]
            row += count
        else:
            nbytes = dt.itemsize * count
            if offset + nbytes > len(data):
                raise ValueError(
                    f"{path}: element '{name}' needs {nbytes} bytes, file body has "
                    f"{len(data) - offset}"
                )
            arr = np.frombuffer(data, dtype=dt, count=count, offset=offset)
            arr = arr.astype(np.dtype([(p, "=" + _PLY_TYPES[t]) for t, p in props]))
            offset += nbytes
        if name == element:
            return arr
    raise ValueError(f"{path}: no element '{element}'")


# --------------------------------------------------------------------------------------------------
# trained run -> .ply
# --------------------------------------------------------------------------------------------------
@torch.no_grad()
def model_gaussians_at(
    model, t: float, exposure: Optional[float] = None
) -> Dict[str, torch.Tensor]:
    """Activated Gaussians of a TrainedModel at time t with tone-mapped colours.

    Returns dict: means [N,3], quats [N,4] (wxyz, unit), scales [N,3], opacities [N], hdr [N,3] (the
    colour MLP's HDR irradiance, view-independent: a view-dependent MLP is evaluated at the zero
    direction, as stage 1 trains it, without specular lobes; times the Gaussian's gain at t when the
    model has a gain over time), rgb [N,3] = tm(hdr, log2 dt) in [0, 1] (dt =
    exposure, default 1), is_dynamic [N]."""
    dt = 1.0 if exposure is None else float(exposure)
    if not dt > 0:
        raise ValueError(f"exposure must be > 0, got {exposure!r}")
    g = model.gauss
    hdr = gaussian_colors(g, model.color, float(t))
    rgb = model.tm(hdr, torch.tensor(float(np.log2(dt)), dtype=hdr.dtype, device=hdr.device)).clamp(
        0, 1
    )
    return {
        "means": g.positions(float(t)),
        "quats": g.quats(float(t)),
        "scales": g.scales(),
        "opacities": g.opacities(),
        "hdr": hdr,
        "rgb": rgb,
        "is_dynamic": g.is_dynamic,
    }


def export_run_ply(
    run_dir, g: int, out_path, exposure: Optional[float] = None, device: str = "cpu", model=None
) -> Path:
    """Write the Gaussians of a trained run at the time of global frame g as a standard 3DGS .ply.

    Args:
        run_dir: run folder (model/final.pt, run.json). g: global frame index (test frames:
        interpolated time). out_path: output file. exposure: dt baked into the LDR colour through
        the learned tone mapper (default 1,
            the unit exposure). device: where the model is evaluated. model: an already loaded
            TrainedModel (skips loading run_dir).
    Returns:
        the written path.
    """
    if exposure is not None and not (math.isfinite(exposure) and exposure > 0):
        raise InputError(f"--exposure must be a finite exposure time > 0; got {exposure}")
    if model is None:
        model = load_model(run_dir, device=device)
    frames = model.clip.meta.frames
    if int(g) not in set(frames):
        raise InputError(
            f"{run_dir}: frame {g} is not a frame of the clip {model.clip.root} "
            f"(frames {min(frames)}..{max(frames)})"
        )
    t = model.time_of(g)
    dt = 1.0 if exposure is None else float(exposure)
    gs = model_gaussians_at(model, t, dt)
    arr = gaussians_to_ply_arrays(
        gs["means"], gs["quats"], gs["scales"], gs["opacities"], gs["rgb"]
    )
    n_dyn = int(gs["is_dynamic"].sum())
    comments = [
        f"m4dgs Mono4DGS-HDR export: run={Path(run_dir).name} frame={int(g)} time={t:.6g} "
        f"exposure_dt={dt:.6g} "
        f"colour=learned tone mapper at dt (LDR, SH degree 0) static={arr.shape[0] - n_dyn} "
        f"dynamic={n_dyn}",
        "m4dgs coordinates: estimated world frame, OpenCV convention (x right, y down, z "
        "forward), arbitrary scale",
    ]
    return write_ply(out_path, arr, comments)
