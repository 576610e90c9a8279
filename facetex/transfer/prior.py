"""Facial prior regularisation (FaceTex Sec. 2.2): identity forward, gradient × mask backward.

Placed on the image, in front of the feature networks, as in the authors' code
(``mylib/faceprior.lua`` ``nn.FacePriorLayer``, inserted after the TV layer and before the
first VGG layer of both networks). Consequences worth keeping:

- the mask scales the gradients of the network losses (MRF on VGG-19 *and* the content /
  structure loss on VGG-Face) but not the TV gradient, whose layer sits before the prior;
- the mask is resized (bilinear) to the image size of each resolution level. The layer keeps
  the full-size base mask and resizes it on a size change (the CUDA path resamples the base;
  the CPU path rescales the previous level's mask); :class:`FacialPrior` resamples the base;
- the mask itself (``mylib/maskLoader.lua``) is 1 − min-max-normalised blur of the
  meso-structure contour image, multiplied by a face-region mask (so the background is not
  updated at all — the paper does not say so). The blur is ``image.gaussian(65, 30)``,
  whose sigma torch7 reads relative to the kernel size, i.e. (to our reading) a nearly flat
  65×65 kernel rather than the paper's "Gaussian blur". Its construction belongs to
  ``facetex.geometry.masks``, not here;
- the paper's contours come from 66 CLM landmarks [19]; the code loads a prepared PNG.

What the prior does *not* do: under L-BFGS a gradient mask > 0 is only a preconditioner —
the curvature pairs undo a per-pixel scaling (a pixel scaled by 0.05 moved 0.666 against
0.658 unscaled), so eyes, nose and mouth still change; only pixels with mask exactly 0 stay
put. The ``paper`` preset keeps this layer as the paper describes it; the ``default`` preset
instead optimises a masked change ``x = c + m ⊙ z`` over the content's skin
(``optimize_image(change_mask=...)``), a hard constraint: eyes, brows, lips, nostrils, hair and
background cannot change at all.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..errors import BadInputError

__all__ = ["FacialPriorGrad", "apply_facial_prior", "resize_mask", "FacialPrior"]


def _broadcast_mask(mask: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    if mask.ndim == 2:
        mask = mask[None, None]
    if mask.ndim != 4 or mask.shape[1] != 1 or mask.shape[-2:] != x.shape[-2:] or mask.shape[0] not in (1, x.shape[0]):
        raise BadInputError(
            f"prior mask of shape {tuple(mask.shape)} does not fit an image of shape {tuple(x.shape)}: "
            "pass (H, W) or (N, 1, H, W) of the image size (see resize_mask)")
    return mask.to(dtype=x.dtype, device=x.device)


class FacialPriorGrad(torch.autograd.Function):
    """y = x; ∂L/∂x = mask ⊙ ∂L/∂y (the mask gets no gradient)."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(mask)
        return x.view_as(x)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        (mask,) = ctx.saved_tensors
        return grad * mask, None


def apply_facial_prior(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Identity on x (N, C, H, W) whose backward multiplies the gradient by ``mask``
    ((H, W) or (N, 1, H, W), broadcast over channels; 0 freezes a pixel, 1 leaves it free)."""
    if x.ndim != 4:
        raise BadInputError(f"apply_facial_prior expects an (N, C, H, W) tensor, got shape {tuple(x.shape)}")
    return FacialPriorGrad.apply(x, _broadcast_mask(mask, x).detach())


def resize_mask(mask: torch.Tensor | "np.ndarray", size: tuple[int, int]) -> torch.Tensor:  # noqa: F821
    """Bilinear resize of an (H, W) or (N, 1, H, W) mask to ``size`` (h, w), as the authors'
    layer does per resolution level (``image.scale``); antialiased when shrinking."""
    m = torch.as_tensor(mask)
    squeeze = m.ndim == 2
    if squeeze:
        m = m[None, None]
    m = m.float() if not m.is_floating_point() else m
    if tuple(m.shape[-2:]) != tuple(size):
        shrink = size[0] < m.shape[-2] or size[1] < m.shape[-1]
        m = F.interpolate(m, size=tuple(size), mode="bilinear", align_corners=False, antialias=shrink)
    return m[0, 0] if squeeze else m


class FacialPrior(nn.Module):
    """Module form of :func:`apply_facial_prior` holding a full-size base mask that is
    resized (and cached) for each input size, like ``nn.FacePriorLayer``."""

    def __init__(self, mask: torch.Tensor | "np.ndarray"):  # noqa: F821
        super().__init__()
        base = torch.as_tensor(mask).float()
        if base.ndim not in (2, 4):
            raise BadInputError(f"prior mask must be (H, W) or (N, 1, H, W), got shape {tuple(base.shape)}")
        self.register_buffer("base", base)
        self._cache: tuple[tuple[int, int], torch.Tensor] | None = None

    def mask_for(self, size: tuple[int, int]) -> torch.Tensor:
        """The base mask resized to ``size`` (h, w)."""
        size = (int(size[0]), int(size[1]))
        if self._cache is None or self._cache[0] != size or self._cache[1].device != self.base.device:
            self._cache = (size, resize_mask(self.base, size))
        return self._cache[1]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return apply_facial_prior(x, self.mask_for(x.shape[-2:]))
