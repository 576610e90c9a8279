"""Geometry shared by FaceTex and Persona — pure numpy / OpenCV / SciPy, no torch.

- :mod:`.tps`: thin-plate splines with smoothing (Tom Hanks Eq. 1)
- :mod:`.morph`: Beier–Neely and piecewise-affine morphs
- :mod:`.style_align`: FaceTex's style-to-content alignment, :func:`align_style_to_content`
- :mod:`.flow`: dense correspondence (variational optical flow, SIFT-flow-like), flow utilities
- :mod:`.frontalize`: head pose by PnP on a generic 3D face, frontalization
- :mod:`.masks`: the FaceTex facial prior mask, the face-region mask, polygon and feature masks
- :mod:`.skin`: skin masks (face region, features, the face's skin colour, beards)
- :mod:`.segment`: face segmentation into skin, hair, brows, beard, highlights
- :mod:`.glasses`: eyeglasses in a face photo (the frame's bridge over the nose) and their rims in a video
- :mod:`.gaze`: sideways gaze in a face photo (the balance of the eyes' whites)
"""

from .._lazy import lazy_attributes as _lazy_attributes

# eager: the function `frontalize` must win over its submodule of the same name
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

#: public name -> the private module that defines it (imported on first use: importing one
#: submodule, e.g. the driver tracker in its own process, does not load them all)
_LAZY = {
    "compose_flows": "flow",
    "flow_epe": "flow",
    "flow_from_map": "flow",
    "invert_flow": "flow",
    "map_from_flow": "flow",
    "optical_flow": "flow",
    "sift_flow": "flow",
    "warp_with_flow": "flow",
    "REF_FACE_WIDTH": "masks",
    "face_mask": "masks",
    "face_outline": "masks",
    "face_width": "masks",
    "facial_prior_mask": "masks",
    "prior_mask": "masks",
    "AlignParams": "style_align",
    "AlignResult": "style_align",
    "BeierNeelyParams": "morph",
    "align_style_to_content": "style_align",
    "beier_neely_map": "morph",
    "beier_neely_warp": "morph",
    "compose_maps": "morph",
    "piecewise_affine_map": "morph",
    "piecewise_affine_warp": "morph",
    "remap": "morph",
    "ThinPlateSpline": "tps",
    "tps_evaluate_many": "tps",
    "tps_warp": "tps",
}

__getattr__, __dir__ = _lazy_attributes(__name__, globals(), _LAZY)


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
