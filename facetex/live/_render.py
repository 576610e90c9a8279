"""The live rendering in a child process (:class:`ProcessRenderer`, on
:class:`~facetex.live._workers.ChildWorker`): the child renders and composites frame t while this
process makes the mesh and texture of frame t+1 (each holds its own GIL).

The child gets a copy of the :class:`facetex.puppet.Puppeteer` with what its ``render`` reads only
(the puppet's triangulation, texture coordinates, normals, parameters; no persona, no deformation
transfer), and per frame the frame's pose, tracked landmarks and mesh, the puppet's grid and texture
and the driver panel; it returns the uint8 output."""

from __future__ import annotations

import copy
from types import SimpleNamespace

import numpy as np

__all__ = ["render_kit", "ProcessRenderer"]


def render_kit(pup):
    """A picklable copy of a Puppeteer with one frame slot, for :meth:`Puppeteer.render` only."""
    if pup.params.composite.eyes == "driver":
        pup.iris()  # measured on the persona's photos, which the kit does not carry
    kit = copy.copy(pup)
    kit.persona = kit.transfer = kit.correspondence = None
    kit.lip_fields = kit.brow_fields = kit.lid_fields = None
    kit._sequence_weights = None
    kit.motion = SimpleNamespace(pose_A=np.zeros((1, 3, 3)), pose_b=np.zeros((1, 3)), grid_step=pup.motion.grid_step,
                                 triangles=pup.motion.triangles)
    kit.track = SimpleNamespace(points68=np.zeros((1, 68, 2)), mesh=np.zeros((1, 468, 3)),
                                rims=pup.track.rims)
    return kit


def render_frame(kit, frame: dict, grid, texture, panel: np.ndarray, scale: float, mode: str) -> np.ndarray:
    """uint8 output of one frame with a :func:`render_kit` (``frame``: its A, b, points68, mesh;
    ``panel``: the driver panel, uint8)."""
    from ..io import to_uint8

    kit.motion.pose_A[0], kit.motion.pose_b[0] = frame["A"], frame["b"]
    kit.track.points68[0], kit.track.mesh[0] = frame["points68"], frame["mesh"]
    img, _ = kit.render(0, grid, texture, panel.astype(np.float32) * np.float32(1 / 255), scale, mode)
    return to_uint8(img)


class _Renderer:
    """The child's object: started at once (its imports made), given the kit when the puppet is made."""

    def __init__(self):
        import cv2

        from ..puppet import composite, puppeteer, render  # noqa: F401 - imported now, not at the first frame

        # OpenCV builds its CIELAB tables at the first conversion (~0.1 s): now, not in the first frame
        for code in (cv2.COLOR_LRGB2Lab, cv2.COLOR_Lab2RGB, cv2.COLOR_RGB2Lab, cv2.COLOR_Lab2LRGB):
            cv2.cvtColor(np.zeros((1, 1, 3), np.float32), code)
        self.kit = None

    def set_kit(self, kit, *first) -> None:
        """The kit, and one frame rendered with it when ``first`` (render_frame's arguments) is given:
        the first calls' set-up is then not paid by the first live frame."""
        self.kit = kit
        if first:
            render_frame(kit, *first)

    def render(self, *args):
        return render_frame(self.kit, *args)


def _make_renderer() -> _Renderer:
    return _Renderer()


class ProcessRenderer:
    """:func:`render_frame` in a child process, started now; :meth:`set_kit` once the puppet is made
    (OSError: no child could be started)."""

    def __init__(self):
        from ._workers import worker

        self._child = worker("facetex.live._render:_make_renderer", name="live rendering")

    def wait_ready(self) -> None:
        self._child.wait_ready()

    def set_kit(self, kit, *first) -> None:
        """Hand the child its kit (and a first frame to render; not waited for: the next call queues
        behind it)."""
        self._child.cast("set_kit", kit, *first)

    def __call__(self, frame: dict, grid, texture, panel, scale: float, mode: str) -> np.ndarray:
        return self._child.call("render", frame, grid, texture, panel, scale, mode)

    def close(self) -> None:
        self._child.close()
