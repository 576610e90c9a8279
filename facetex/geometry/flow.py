"""Dense correspondence: flow-field utilities, variational optical flow, SIFT flow.

Flow convention
---------------
A flow is a float32 array of shape (H, W, 2) holding (dx, dy) in pixels.
``warp_with_flow(image, flow)`` is a BACKWARD warp::

    out(x) = image(x + flow(x))          (bilinear, border replicate; cv2.remap)

"The flow from A to B" is the field F with ``A(x) ≈ B(x + F(x))``, so
``warp_with_flow(B, F) ≈ A``: it pulls B onto A's geometry. Composition follows
from this: with F_ab (A->B) and F_bc (B->C), ``compose_flows(F_ab, F_bc)`` is
the flow A->C, i.e. ``warp(warp(C, F_bc), F_ab) ≈ warp(C, compose)``.

Two estimators:

* :func:`optical_flow` -- same person, illumination-matched pairs (Tom Hanks
  §4/§5: Brox et al. 2004 / Bruhn et al. 2005, Ce Liu's Coarse2FineFlow
  parameters). Methods live in :mod:`facetex.geometry._optical_flow`.
* :func:`sift_flow` -- different people (FaceTex §2.3, Liu et al. 2011): dense
  SIFT descriptors matched coarse-to-fine with a truncated-L1 smoothness prior.
  Implementation in :mod:`facetex.geometry._sift_flow`.
"""

from __future__ import annotations

from ._flow_core import compose_flows, flow_epe, flow_from_map, invert_flow, map_from_flow, warp_with_flow
from ._optical_flow import optical_flow
from ._sift_flow import sift_flow

__all__ = [
    "warp_with_flow",
    "compose_flows",
    "invert_flow",
    "flow_from_map",
    "map_from_flow",
    "flow_epe",
    "optical_flow",
    "sift_flow",
]
