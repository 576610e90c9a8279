"""The puppet's and the driver's average shapes and their correspondence (Tom Hanks §4, §6;
step 1-2 of :mod:`facetex.puppet.puppetry`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import BadInputError
from .driver import DriverTrack
from .params import PuppetParams

__all__ = [
    "puppet_average_shape",
    "DriverCollection",
    "driver_collection",
    "collection_correspondence",
    "landmark_correspondence",
]


# ----------------------------------------------------------------------------- shapes
def puppet_average_shape(persona, params: PuppetParams = PuppetParams()) -> tuple[np.ndarray, np.ndarray, str]:
    """(depth (H, W) canonical px, mask (H, W) bool, source "collection" | "generic") of the
    persona's average 3D face (Tom Hanks §4): the one stored in the .persona (computed at
    build time), else computed now (version-1 files); cached on the persona object."""
    from ..persona.align import face_region
    from ..persona.build import average_depth
    from .shape import checked_depth

    key = ("puppet_shape", params.max_depth_error, params.shape, params.shape_photos)
    if key not in persona._cache:
        W, H = persona.size
        region = face_region(persona.points68.mean(axis=0), (H, W))
        depth = None
        if params.shape == "collection":
            stored = persona.depth is not None and params.shape_photos == persona.params.shape_photos
            depth = persona.depth if stored else average_depth(persona, shape_photos=params.shape_photos)[0]
        depth, src = checked_depth(depth, region, persona.size, params.max_depth_error)
        persona._cache[key] = (depth, region, src)
    return persona._cache[key]


@dataclass(eq=False)
class DriverCollection:
    """The driver's canonical-frame collection data: subspace (1 + rank, H, W, 3) (mean first),
    region (H, W) bool, depth (H, W) or None (use the tracked mean mesh), source text."""

    subspace: np.ndarray | None  # None: tracked without frontal images (landmark correspondence)
    region: np.ndarray
    depth: np.ndarray | None
    source: str


def driver_collection(track: DriverTrack, *, driver_photos=None, params: PuppetParams = PuppetParams(),
                      progress: Callable | None = None) -> DriverCollection:
    """The driver's 2D average, appearance subspace and (with photos) average shape.

    From ``driver_photos`` (a folder): a persona build of it (fewest photos 4). Otherwise the
    frontalized video frames kept by :func:`~facetex.puppet.driver.track_driver`, TPS-aligned to
    their mean fiducials."""
    from ..landmarks import POINTS49_INDEX
    from ..persona.align import appearance_subspace, face_region, remap_stack, tps_maps
    from ..persona.collection import PersonaParams
    from ..persona.build import build_persona
    from .shape import checked_depth

    W, H = params.driver.size
    if driver_photos is not None:
        dp = build_persona(driver_photos, jobs=1, progress=progress,
                           params=PersonaParams(size=(W, H), min_photos=4, shape_photos=params.shape_photos))
        region = face_region(dp.points68.mean(axis=0), (H, W))
        depth, src = checked_depth(dp.depth, region, (W, H), params.max_depth_error)
        return DriverCollection(dp.subspace, region, depth, f"photos ({len(dp)}, shape: {src})")
    if len(track.frontal) == 0:  # tracked for the landmark correspondence: no appearance subspace
        region = face_region(track.frontal_points68.mean(axis=0), (H, W))
        return DriverCollection(None, region, None, f"video frames ({len(track.frontal_points68)} landmark sets, "
                                                    "shape: tracked mean mesh)")
    fid = track.frontal_points68[:, POINTS49_INDEX]
    M = fid.mean(axis=0)
    maps = tps_maps(fid, M, (H, W), 10.0)
    warped = remap_stack(track.frontal, maps)
    region = face_region(track.frontal_points68.mean(axis=0), (H, W))
    sub, _ = appearance_subspace(warped, region, 4)
    return DriverCollection(sub, region, None, f"video frames ({len(warped)}, shape: tracked mean mesh)")


def collection_correspondence(driver_subspace: np.ndarray, driver_region: np.ndarray, puppet_average: np.ndarray,
                              params: PuppetParams = PuppetParams()) -> np.ndarray:
    """(H, W, 2) puppet-frame (x, y) of every driver-frame pixel (Tom Hanks §4, §6): the flow
    from the projection of the puppet's average onto the driver's appearance subspace to the
    puppet's average (illumination-matched pair; collection flow)."""
    from ..geometry.flow import map_from_flow, optical_flow
    from ..persona.align import project_onto_subspace

    proj = np.clip(project_onto_subspace(puppet_average, driver_subspace, driver_region), 0, 1)
    flow = optical_flow(proj, puppet_average, alpha=params.flow_alpha, ratio=params.flow_ratio,
                        min_width=params.flow_min_width, outer_iters=params.flow_outer,
                        inner_iters=params.flow_inner, sor_iters=params.flow_sor)
    return map_from_flow(flow)


def landmark_correspondence(driver_points68, puppet_points68, shape, smoothing: float = 10.0) -> np.ndarray:
    """(H, W, 2) puppet-frame (x, y) of every driver-frame pixel: the thin-plate spline (Eq. 1,
    ``smoothing`` λ) that maps the driver's mean landmarks (68, 2) onto the puppet's (both in the
    canonical frame). Smooth and fold-free, exact at the landmarks (:mod:`facetex.puppet.puppetry` doc, 2)."""
    from ..persona.align import tps_map

    d = np.asarray(driver_points68, np.float64)
    p = np.asarray(puppet_points68, np.float64)
    if d.shape != (68, 2) or p.shape != (68, 2) or not (np.isfinite(d).all() and np.isfinite(p).all()):
        raise BadInputError(f"landmark correspondence needs two finite (68, 2) landmark sets, got {d.shape}, {p.shape}")
    return tps_map(d, p, shape, smoothing)


