"""Geometry shared by FaceTex and Persona — pure numpy / OpenCV / SciPy, no torch.

- :mod:`.tps`: thin-plate splines with smoothing (Tom Hanks Eq. 1)
- :mod:`.morph`: Beier–Neely and piecewise-affine morphs, :func:`align_style_to_content`
- :mod:`.flow`: dense correspondence (variational optical flow, SIFT-flow-like), flow utilities
- :mod:`.frontalize`: head pose by PnP on a generic 3D face, frontalization
- :mod:`.masks`: the FaceTex facial prior mask and the face-region mask
"""

from .flow import compose_flows, flow_epe, flow_from_map, invert_flow, map_from_flow, optical_flow, sift_flow, warp_with_flow
from .frontalize import (
    CANONICAL_SIZE,
    Frontalized,
    HeadPose,
    canonical_points68,
    estimate_head_pose,
    frontalize,
    pose_corrected_points68,
    rotate_face,
    rotation_from_angles,
)
from .masks import REF_FACE_WIDTH, face_mask, face_outline, face_width, facial_prior_mask, prior_mask
from .morph import (
    AlignParams,
    AlignResult,
    BeierNeelyParams,
    align_style_to_content,
    beier_neely_map,
    beier_neely_warp,
    compose_maps,
    piecewise_affine_map,
    piecewise_affine_warp,
    remap,
)
from .tps import ThinPlateSpline, tps_evaluate_many, tps_warp

__all__ = [
    "ThinPlateSpline", "tps_evaluate_many", "tps_warp",
    "BeierNeelyParams", "AlignParams", "AlignResult", "align_style_to_content", "beier_neely_map", "beier_neely_warp",
    "piecewise_affine_map", "piecewise_affine_warp", "remap", "compose_maps",
    "warp_with_flow", "compose_flows", "invert_flow", "flow_from_map", "map_from_flow", "flow_epe", "optical_flow",
    "sift_flow",
    "HeadPose", "Frontalized", "estimate_head_pose", "frontalize", "pose_corrected_points68", "canonical_points68",
    "rotate_face",
    "rotation_from_angles", "CANONICAL_SIZE",
    "REF_FACE_WIDTH", "face_mask", "face_outline", "face_width", "facial_prior_mask", "prior_mask",
]
