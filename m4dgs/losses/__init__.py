"""Loss functions of Mono4DGS-HDR (paper Sec. 3.3.3 and appendix); re-exports of the submodules'
public API."""

from m4dgs.losses.geometry import (
    depth_loss,
    destination_pixels,
    flow_from_destination_map,
    flow_loss,
    normalize_by_alpha,
    track_loss,
)
from m4dgs.losses.motion import (
    acceleration_loss,
    arap_loss,
    quat_relative_angle,
    smoothness_terms,
    velocity_loss,
    window_times,
)
from m4dgs.losses.photometric import dssim_loss, l1_loss, rgb_loss, unit_exposure_loss
from m4dgs.losses.temporal import (
    hdr_reprojection_loss,
    ldr_reprojection_loss,
    relative_difference,
    reprojection_coords,
    tlr_loss,
    tlr_loss_neighbours,
    tlr_valid_mask,
)

__all__ = [
    "acceleration_loss",
    "arap_loss",
    "depth_loss",
    "destination_pixels",
    "dssim_loss",
    "flow_from_destination_map",
    "flow_loss",
    "hdr_reprojection_loss",
    "l1_loss",
    "ldr_reprojection_loss",
    "normalize_by_alpha",
    "quat_relative_angle",
    "relative_difference",
    "reprojection_coords",
    "rgb_loss",
    "smoothness_terms",
    "tlr_loss",
    "tlr_loss_neighbours",
    "tlr_valid_mask",
    "track_loss",
    "unit_exposure_loss",
    "velocity_loss",
    "window_times",
]
