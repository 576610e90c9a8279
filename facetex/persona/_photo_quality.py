"""Each persona photo's quality weights, computed once from the texture stacks: the detail of its
eyes (open, sharp eyes with visible whites and iris), its gaze (photos looking sideways count
less), how unlikely it shows eyeglasses, and its band energy per level and region (what the detail
restoration gives back). Mixed into :class:`facetex.persona.stacks._Prepared`,
whose stacks, shapes and per-photo scores they read."""

from __future__ import annotations

import cv2
import numpy as np

from ..geometry.gaze import gaze_weights
from ..geometry.glasses import glasses_bridge_score
from ..geometry.masks import disc
from ..landmarks import eye_distance
from .params import GLASSES_LEVELS


class _PhotoQuality:
    """The per-photo weights of :class:`facetex.persona.stacks._Prepared` (see the module doc)."""

    #: pyramid levels (finest = 0) whose band energy measures a photo's eye detail: 2-8 px
    #: structures (lids, iris against the whites) at the 192 x 240 canonical frame
    QUALITY_LEVELS = (1, 2)

    def eye_quality(self) -> np.ndarray:
        """(n,) detail confidence of each photo's eyes: its band energy (levels
        :data:`QUALITY_LEVELS`, RGB, confidence-weighted) inside both eyes' outlines (grown by
        0.1 IOD) over the collection's median, to the power ``tp.eye_quality`` / 2 (the band's
        amplitude to the power ``eye_quality``), clipped to [1/4, 4]. Open, sharp eyes with visible
        whites and iris have the most energy there; shut, blurred or shadowed ones the least
        (the per-pixel L^alpha of Eq. 2 favoured JPEG blocks and noise: one number per photo over
        the eyes does not); times each photo's gaze weight (``tp.gaze``: photos looking sideways
        count less). Computed from the stacks once."""
        key = ("eye_quality", self.tp.eye_quality, self.tp.gaze)
        if key not in self._stage:
            from ..geometry.masks import polygon_mask

            p = self.points68
            iod = eye_distance(p)
            H, W = self.shape
            m = np.maximum(polygon_mask(p[36:42], (H, W)), polygon_mask(p[42:48], (H, W))) > 0.5
            r = max(1, int(round(0.1 * iod)))
            m = cv2.dilate(m.astype(np.uint8), disc(r))
            m = m.astype(np.float32)
            num = np.zeros(self.n)
            den = np.zeros(self.n)
            for k in range(self.levels):
                if k > 0:
                    m = cv2.resize(m, self.level_shapes[k][::-1], interpolation=cv2.INTER_AREA)
                if k not in self.QUALITY_LEVELS:
                    continue
                inside = m.reshape(-1) > 0.25
                for seg in self.segments[k]:
                    sel = inside[seg.pixels]
                    if not sel.any():
                        continue
                    rows = seg.stack.reshape(self.n, -1, 4)[:, sel].astype(np.float64)
                    c = rows[..., 3]
                    band2 = (rows[..., :3] ** 2).sum(-1) / np.maximum(c, 1e-6)  # |band|^2 c from (band c)^2 / c
                    num += band2.sum(-1)
                    den += c.sum(-1)
            e = num / np.maximum(den, 1e-12)
            med = float(np.median(e)) if np.median(e) > 0 else 1.0
            q = np.clip((e / med) ** (self.tp.eye_quality / 2.0), 0.25, 4.0)
            # not clipped: a sharp photo looking sideways must lose to the next nearest photos even
            # when its expression weight is the largest (the 4th power of the eyes' detail weights)
            self._stage[key] = q * gaze_weights(self._gaze, self.tp.gaze)
        return self._stage[key]

    def glasses_factors(self) -> dict[int, np.ndarray]:
        """{region index: (n,) :meth:`glasses_free` factors} of the regions in
        :data:`GLASSES_LEVELS`, each at its own level: what the blend multiplies their weights by."""
        return {j: self.glasses_free(GLASSES_LEVELS[name]) for j, name in enumerate(self.regions)
                if name in GLASSES_LEVELS}

    def glasses_free(self, level: float) -> np.ndarray:
        """(n,) weight in (0, 1] of each photo by how unlikely it shows eyeglasses
        (:func:`facetex.geometry.glasses.glasses_weights` of the photos' bridge scores from
        ``level`` x their median, exponent ``tp.glasses``), once per level. The frames' rims are
        strong fine detail round the eyes: the eye-detail weights favoured exactly those photos."""
        key = ("glasses", self.tp.glasses, level)
        if key not in self._stage:
            from ..geometry.glasses import glasses_weights

            self._stage[key] = glasses_weights(self._glasses_scores(), level=level, power=self.tp.glasses)
        return self._stage[key]

    def _glasses_scores(self) -> np.ndarray:
        """(n,) every photo's :func:`facetex.geometry.glasses.glasses_bridge_score` (NaN: none):
        made with the stacks or stored with them; computed from the photos otherwise (a file
        from before they were stored)."""
        if self._glasses is None:
            P = self._persona_ref
            self._glasses = np.array([glasses_bridge_score(im, p) for im, p in zip(P.images, P.points68)], np.float64)
        return self._glasses

    def band_energy(self) -> np.ndarray:
        """(levels, R, n) each photo's mean band energy |band|^2 (RGB summed, confidence-weighted)
        per pyramid level and weight region (its mask-weighted pixels), from the stacks, once."""
        if "band_energy" not in self._stage:
            R = len(self.regions)
            num = np.zeros((self.levels, R, self.n))
            den = np.zeros((self.levels, R, self.n))
            for k, segs in enumerate(self.segments):
                for seg in segs:
                    for i0 in range(0, self.n, self.CHUNK):  # a chunk of photos at a time (memory)
                        rows = seg.stack[i0:i0 + self.CHUNK].reshape(-1, len(seg.pixels), 4)
                        c = rows[..., 3]
                        e = (rows[..., 0] ** 2 + rows[..., 1] ** 2 + rows[..., 2] ** 2) / np.maximum(c, 1e-6)
                        for mj, j in zip(seg.masks[:, ::4], seg.regions):  # (band c)^2 / c = |band|^2 c
                            num[k, j, i0:i0 + len(rows)] += e @ mj
                            den[k, j, i0:i0 + len(rows)] += c @ mj
            self._stage["band_energy"] = num / np.maximum(den, 1e-12)
        return self._stage["band_energy"]
