"""Settings of the persona's textures (:class:`TextureParams`: the paper's Eq. 3 constants and ours) and
their choices."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "TextureParams",
    "METHODS",
    "STAGES",
    "WEIGHTS",
    "GLASSES_LEVELS",
    "RENDER_RESTORE",
]


METHODS = ("ours", "static", "weighted", "prewarp")
STAGES = ("a", "b", "c", "d")


@dataclass(frozen=True)
class TextureParams:
    """Parameters of the texture blend: the paper's Eq. 3 constants (alpha, beta, tau) = (1, 20, 1),
    sigma = 10 (Tom Hanks Sec. 6) and ours (module docstring).

    weights: "regional" (ours, default, :mod:`facetex.persona.weights`) or "global" (the paper's
    Eq. 2/3: ``sigma``, alpha 1); neighbours: K of the regional weights' adaptive sigma;
    max_photos: at most this many photos per region and target (regional weights);
    alpha: exponent of the Laplacian response L in Eq. 3, None = 1 with the global weights (the
    paper) and 0 with the regional ones (measured: L^1 favours the photos with the most
    high-frequency energy, i.e. JPEG blocks, noise and harsh light, and costs 0.015-0.025
    leave-out SSIM); min_level_side: the pyramid's coarsest level (px, smaller side);
    mirror_weight / face_support / visibility_floor: the per-photo confidence
    (:func:`facetex.geometry.frontalize.fill_confidence`); regions: the weight regions;
    detail: (region, power, levels): the finest ``levels`` pyramid levels of ``region`` blend its
    weights raised to ``power`` (:func:`facetex.persona.weights.detail_weights`: the detail
    bands from the few photos nearest the expression, the coarse ones from the broad average;
    the eyes' whole expression-weighted pyramid, the rest of the face's two finest bands);
    eye_quality: exponent of each photo's eye-detail confidence in the eyes' detail weights
    (:meth:`_Prepared.eye_quality`; 0: none); gaze: that confidence is multiplied by
    :func:`facetex.geometry.gaze.gaze_weights` with this sigma (0: off): a sharp photo looking
    sideways gave a puppet whose eyes looked off camera whatever the driver did; glasses: exponent of the penalty of photos with
    eyeglasses in the eyes' and the face's weights (:meth:`_Prepared.glasses_free`; 0: none: a
    collection with a few glasses photos drew the frames as ghost rings round the puppet's eyes);
    restore: (region, levels): the finest ``levels`` bands of ``region`` get their photos' own
    band energy back (:meth:`_Prepared._restore_detail`), the gain at most ``restore_gain``. The
    rest of the face's only, not the mouth's: restoring the mouth's three finest bands cost 0.009-0.011
    leave-out mouth SSIM against static on all four 44-71-photo LFW collections (Arroyo +0.014 ->
    +0.023, Williams +0.029 -> +0.040, Koizumi +0.019 -> +0.029, Chavez +0.018 -> +0.029 without it;
    its finest band alone or its two finest still cost 0.001-0.005) and 0.023 on Blair (124 photos:
    +0.026 -> +0.050); face SSIM +0.002-0.006, eyes unchanged. The puppet keeps it (:data:`RENDER_RESTORE`, :meth:`facetex.puppet.PuppetParams.texture_params`):
    averaged lips are pale and blurred and dlib read the puppet's mouth opening 0.55-0.7 as wide as its
    mesh's; taking the mouth's detail from the few nearest photos instead, as the eyes', read as well
    but cost 0.04 leave-out mouth SSIM on a 44-photo collection, restoring 0.01.
    Measured and not the cause of the mouth's gap (Arroyo, 24 photos in the persona): alignment (the
    held-out photo's own texture sent to the neutral frame and back scores mouth SSIM 0.996); the
    neutral frame (each photo warped from its own fiducials straight to the target's, then blended,
    scores the same as the blend in the neutral frame, within 0.0005); what the fiducials can
    choose (the 4 photos with the best mouth SSIM, an oracle, blended: +0.055; the nearest photo alone:
    -0.050; the expression weights' rank correlation with the photos' own SSIM: 0.43).
    robust: (region, kappa): in ``region``'s expression-weighted bands each photo's pixel weight is
    multiplied by 1 / (1 + (d / (kappa s))^2), d its band's distance from the weighted mean there
    and s the median distance (:func:`facetex.persona._stack_parts._robust_product`): a hand over the
    mouth in 2 of Williams' 52 photos drew pale finger shapes under the puppet's closed lips
    (GRID lrwp9a), gone at kappa 2; leave-out mouth SSIM over static (5 folds) +0.001-0.002 on all
    six LFW collections (Bush +0.036 -> +0.037, Blair +0.043 -> +0.045, Williams +0.047 -> +0.047,
    Chavez +0.041 -> +0.043, Koizumi +0.024 -> +0.026, Arroyo +0.029 -> +0.030; kappa 1 and 4
    alike; the face region too cost face SSIM 0.0015 on Koizumi).
    occlusion: kappa of the occluders' factors (:mod:`facetex.persona._occlusion`; 0: off): each
    photo's confidence falls where its fine structure departs from its 8 nearest expressions' by
    more than kappa times the collection's median departure there (outside the lips, eyes and
    brows), judged once when the stacks are made and stored with them. Two of Williams' 52 photos
    with a hand over the mouth drew the fingers as streaks across the puppet's cheek on every
    frame of a talking driver (face mode; fainter in the composite); with kappa 2.5 they are gone
    at 100 % (the robust product on the rest of the face, iterated 3 times, took them only in
    part and cost a 32-frame batch's blend 8.6 -> 15-32 ms a frame; judging each photo against
    the whole collection's rank-4 appearance flagged rare expressions and lighting, not only
    occluders). Leave-out gain over static (5 folds), paired per target, off -> on: whole face
    +0.0002 (Koizumi) to +0.0031 (Chavez; Bush +0.0019, Blair +0.0014, Arroyo +0.0019, Williams
    +0.0009), eyes +0.0006 to +0.0024, mouth -0.0010 (Williams) to +0.0006 (s.e. 0.0001-0.0006).
    mouth_mix: ((region, share), ...): the mouth region's weights are this mix of the regions'
    similarities, each normalised over the photos (:func:`facetex.persona.weights.mix_similarities`;
    used when the mouth and every source are weight regions; () = the mouth's own). The 36 lip
    coordinates alone miss what else shapes the mouth's surroundings (cheeks raised in a smile, the
    pose the frontalization leaves) and are noisy on small faces: a photo close in the whole face or
    in the eyes now shares in the mouth. Leave-out mouth SSIM gain over static (5 folds), the mouth's
    own weights -> this mix: Bush +0.0370 -> +0.0406, Blair +0.0450 -> +0.0531, Williams +0.0472 ->
    +0.0543, Chavez +0.0428 -> +0.0463, Koizumi +0.0256 -> +0.0294, Arroyo +0.0300 -> +0.0357 (the
    paired differences +0.0035-0.0081, 2-3 standard errors each; eyes unchanged, whole face
    +0.0007-0.0022). Other shares (mouth 0.2-0.5, face 0.3-0.5, eyes 0-0.33) within 0.002 of this; what else
    was tried is in :mod:`facetex.persona.weights`."""

    sigma: float = 10.0
    alpha: float | None = None
    beta: float = 20.0
    tau: float = 1.0
    iod_ref: float = 69.12
    min_level_side: int = 2
    laplacian_blur: float = 1.0
    laplacian_floor: float = 1e-3
    use_visibility: bool = True
    visibility_floor: float = 0.02
    mirror_weight: float = 0.1
    face_support: float = 0.25
    regions: tuple = ("mouth", "eyes", "face")
    max_photos: int | None = 32
    weights: str = "regional"
    neighbours: int | tuple = 3
    detail: tuple = (("eyes", 4.0, 5), ("face", 2.0, 2))
    eye_quality: float = 1.5
    gaze: float = 0.3
    glasses: float = 4.0
    restore: tuple = (("face", 3),)
    restore_gain: float = 3.0
    robust: tuple = (("mouth", 2.0),)
    occlusion: float = 2.5
    mouth_mix: tuple = (("mouth", 0.4), ("face", 0.4), ("eyes", 0.2))

    def region_mix(self) -> tuple:
        """The weight mix in effect, (("mouth", ((source, share), ...)),) or () (:attr:`mouth_mix`)."""
        names = {"mouth", *(src for src, _ in self.mouth_mix)}
        if not self.mouth_mix or not names <= set(self.regions):
            return ()
        return (("mouth", tuple((src, float(share)) for src, share in self.mouth_mix)),)

    def detail_of(self, region: str) -> tuple[float, int]:
        """(power, levels) of ``region``'s detail weights (:attr:`detail`; (1, 0): none)."""
        for name, power, levels in self.detail:
            if name == region:
                return float(power), int(levels)
        return 1.0, 0

    @property
    def alpha_(self) -> float:
        """alpha in effect (see the class docstring)."""
        if self.alpha is not None:
            return float(self.alpha)
        return 1.0 if self.weights == "global" else 0.0

    @classmethod
    def paper(cls, **kw) -> "TextureParams":
        """The paper's Eq. 3 weights: global, sigma 10, alpha 1 (and none of our occluders' factors,
        which the paper does not have: its stacks are made from the photos as they are)."""
        return cls(**{"weights": "global", "alpha": 1.0, "occlusion": 0.0, **kw})

    def stack_key(self) -> tuple:
        """The fields the precomputed stacks depend on (the weights do not)."""
        key = (self.alpha_, self.min_level_side, self.laplacian_blur, self.laplacian_floor, tuple(self.regions),
               self.use_visibility, self.visibility_floor, self.mirror_weight, self.face_support)
        # stacks made without the occluders' factors keep the key they were stored with
        return key + (("occlusion", float(self.occlusion)),) if self.occlusion > 0 else key


WEIGHTS = ("regional", "global")
#: ``TextureParams.restore`` of the puppet's render: the mouth's detail restored too (legible lips and
#: teeth for the viewer and for dlib reading the puppet back; the persona texture leaves it out, see
#: :class:`TextureParams`)
RENDER_RESTORE = (("face", 3), ("mouth", 3))
#: per weight region, the multiple of the collection's median glasses score above which a photo's
#: weight falls (:meth:`_Prepared.glasses_free`): the eyes' from 1.25 (faint rims at 1.5), the rest
#: of the face's from 2 (strong frames only: from 1.25 it also took weight from 13 of Williams'
#: 52 photos, none with glasses; from 2, Arroyo's faint rims are still gone)
GLASSES_LEVELS = {"eyes": 1.25, "face": 2.0}


