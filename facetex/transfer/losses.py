"""FaceTex losses (Kaur, Zhang & Dana 2017, Eqs. 1–4 and 6) as pure functions on tensors.

Feature maps are (C, H, W) or (1, C, H, W); images (N, C, H, W) or (C, H, W). Every loss
returns a 0-d tensor differentiable w.r.t. its first argument.

The MRF loss (Eqs. 1–2) is hand-written: no library offers a memory-bounded neural-patch
nearest-neighbour loss. Matching runs under ``no_grad`` on unit-normalised style patches,
in blocks of target patches × chunks of style patches with a running argmax, so the
N_t × N_s similarity matrix never exists (:func:`mrf_memory_estimate` bounds the peak).
The loss is then written without materialising the matched patches either:
``Σ_i ‖P_i(x) − S_nn(i)‖² = Σ_p count(p)·‖x(p)‖² − 2·x(p)·R(p) + Q(p)``, where for each
feature position p, ``count`` is the number of target patches covering it, ``R`` the sum of
the matched style values placed there and ``Q`` their squared norms; gradients therefore
flow only through the target features, and matches are recomputed on every call.

Where the authors' code (ComputerVisionRutgers/CNNMRF, a fork of chuanli11/CNNMRF,
``mylib/mrf.lua``, ``content.lua``, ``tv.lua``, ``style.lua``, ``transfer_CNNMRF_wrapper.lua``)
differs from the paper, ``variant="reference"`` follows the code and ``"paper"`` the text:

1. Eq. 1 says argmin of the normalised cross-correlation; both mean the *most* similar
   patch (``torch.max`` of the response in mrf.lua). Both variants take the argmax.
2. Target (synthesised) patches: the paper sums over all N_t patches (stride 1); the code
   keeps only patches on a stride-2 grid (``source_sample_stride=2``, used by the transfer
   wrapper although its help text says "syn only"), though it computes the response densely.
3. Style patches: sampled with stride 2 (``target_sample_stride=2``) and the grid always
   includes the last row/column (``computegrid(..., flag_all=1)``). The paper does not say;
   both variants use this grid (``style_stride=2`` by default).
4. Normalisation: the code divides the response by both patch norms (true NCC); dividing by
   the target norm cannot change the argmax, so only the style norms are used for matching.
5. Confidence threshold: the code drops matches whose NCC is below
   ``mrf_confidence_threshold`` (default 0, so only negative / undefined NCC, e.g. an
   all-zero target patch, is dropped). The paper has no threshold.
6. Gradient: the code returns no loss value (feval returns 0) and its MRF "gradient" is
   ``strength · mean over the kept patches covering p of (x(p) − S_nn(p))`` — no factor 2 and
   divided by the per-position coverage count. That is the exact gradient of
   ``½ Σ_p Σ_{i∋p} ‖x(p) − S_i(p)‖² / count(p)``, which ``"reference"`` returns as its value.
   ``"paper"`` is Eq. 2: the plain sum of squared differences.
7. Content loss (content.lua): ``nn.MSECriterion`` (mean over elements) × weight, on a
   *second* network (VGG-Face, its layer 21 = relu4_2), i.e. Eq. 3 with one layer; the
   paper's Eq. 6 content term is a plain sum. :func:`content_loss` has ``reduction``.
8. TV (tv.lua): gradient-only, over the top-left (H−1)×(W−1) crop, no factor 2, i.e. the
   gradient of ½·Σ_crop(...) — and the TV layer is in both networks, so its effective weight
   is twice ``tv_weight``. ``tv_loss(variant="reference")`` is the ½·crop sum (one layer).
9. Gram (style.lua, neural-style): G = FFᵀ / (C·H·W) and MSE (mean over C² entries); Eq. 6
   writes the squared Frobenius norm and does not state a normalisation.
10. Pixel scale: the code optimises caffe-preprocessed images (BGR, ×256, mean subtracted),
    so its weights (MRF 1e-4, content 2e1, TV 1e-3) do not carry over to [0, 1] RGB inputs.

Preset-level facts of the code the paper leaves unstated (for ``methods.py``): MRF on VGG-19
relu3_1 + relu4_1 (loadcaffe layers 12, 21), 3×3 patches, weight 1e-4 each; the structure
loss on VGG-Face relu4_2 (its layer 21), weight 2e1; TV 1e-3 (counted twice, item 8); images
scaled to max side 384; 3 levels × 100 L-BFGS iterations, each level's style features and
content targets recomputed from the image pyramid (ceil(size / 2^k)); no rotated / scaled
style copies (``target_num_rotation = target_num_scale = 0``); init = content image. The
facial prior and solver differences are listed in ``prior.py`` and ``optimize.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from ..errors import BadInputError

__all__ = [
    "StylePatches", "extract_patches", "style_patches", "mrf_match", "mrf_loss",
    "mrf_memory_estimate", "content_loss", "gram_matrix", "gram_loss", "structure_loss",
    "tv_loss", "channel_softmax", "MRF_VARIANTS", "MRFLoss",
]

# Variant defaults for mrf_loss (see the module docstring, items 2, 5 and 6).
MRF_VARIANTS = {
    "paper": {"target_stride": 1, "threshold": None, "weighting": "sum"},
    "reference": {"target_stride": 2, "threshold": 0.0, "weighting": "coverage"},
}

_BLOCK_ELEMENTS = 2**21  # elements (8 MiB in float32) per target-patch / scatter block
_SCORE_ELEMENTS = 2**22  # elements (16 MiB) per block of target × style similarities
_EPS = 1e-12
_DENSE_ELEMENTS = 2**23  # patch elements (C·k² × target patches) up to which mrf_loss matches in one piece


def _as_chw(feat: torch.Tensor, what: str) -> torch.Tensor:
    if feat.ndim == 4 and feat.shape[0] == 1:
        feat = feat[0]
    if feat.ndim != 3:
        raise BadInputError(f"{what} must be a (C, H, W) or (1, C, H, W) feature map, got shape {tuple(feat.shape)}")
    return feat


def _grid(n: int, size: int, stride: int) -> torch.Tensor:
    """Patch origins along one axis: every ``stride``-th, plus the last one (CNNMRF's flag_all)."""
    if n < size:
        raise BadInputError(f"feature map side {n} is smaller than the patch size {size}: use a larger image")
    pos = list(range(0, n - size + 1, stride))
    if pos[-1] != n - size:
        pos.append(n - size)
    return torch.tensor(pos, dtype=torch.long)


def _window_index(origins: torch.Tensor, size: int) -> torch.Tensor:
    return (origins[:, None] + torch.arange(size)).reshape(-1)


def _gather_patches(feat: torch.Tensor, ys: torch.Tensor, xs: torch.Tensor, size: int) -> torch.Tensor:
    """(len(ys)·len(xs), C·size²) patches at the given origins, row-major, each flattened (C, k, k)."""
    c = feat.shape[0]
    g = feat.index_select(1, _window_index(ys, size).to(feat.device))
    g = g.index_select(2, _window_index(xs, size).to(feat.device))
    g = g.reshape(c, len(ys), size, len(xs), size).permute(1, 3, 0, 2, 4)
    return g.reshape(len(ys) * len(xs), c * size * size)


def _scatter_patches(out: torch.Tensor, patches: torch.Tensor, ys: torch.Tensor, xs: torch.Tensor, size: int) -> None:
    """Add flattened patches (len(ys)·len(xs), C·size²) into ``out`` (C, H, W) at their origins (col2im)."""
    c = out.shape[0]
    p = patches.reshape(len(ys), len(xs), c, size, size).permute(2, 0, 3, 1, 4)
    p = p.reshape(c, len(ys) * size, len(xs) * size)
    cols = torch.zeros(c, len(ys) * size, out.shape[2], dtype=out.dtype, device=out.device)
    cols.index_add_(2, _window_index(xs, size).to(out.device), p)
    out.index_add_(1, _window_index(ys, size).to(out.device), cols)


def extract_patches(feat: torch.Tensor, size: int = 3, stride: int = 1) -> torch.Tensor:
    """Neural patches Ψ(Φ) of a feature map: (L, C, size, size), row-major origins on a
    ``stride`` grid that always includes the last row/column (as CNNMRF samples)."""
    feat = _as_chw(feat, "feat")
    ys, xs = _grid(feat.shape[1], size, stride), _grid(feat.shape[2], size, stride)
    return _gather_patches(feat, ys, xs, size).reshape(-1, feat.shape[0], size, size)


@dataclass(frozen=True)
class StylePatches:
    """Style patches prepared once per resolution: unit-norm rows ``unit`` (N_s, C·k²) and norms."""

    unit: torch.Tensor
    norm: torch.Tensor
    channels: int
    size: int

    def __len__(self) -> int:
        return self.unit.shape[0]

    def patches(self, index: torch.Tensor | None = None) -> torch.Tensor:
        """Flattened style patches (all, or ``index``), reconstructed as unit × norm."""
        if index is None:
            return self.unit * self.norm[:, None]
        return self.unit[index] * self.norm[index, None]


def style_patches(style_feat: torch.Tensor, patch_size: int = 3, stride: int = 2) -> StylePatches:
    """Sample and normalise the style image's neural patches (Eq. 1 denominators)."""
    feat = _as_chw(style_feat, "style_feat").detach()
    ys, xs = _grid(feat.shape[1], patch_size, stride), _grid(feat.shape[2], patch_size, stride)
    dim = feat.shape[0] * patch_size**2
    unit = torch.empty(len(ys) * len(xs), dim, dtype=feat.dtype, device=feat.device)
    rows = max(1, _BLOCK_ELEMENTS // (len(xs) * dim))
    for r0 in range(0, len(ys), rows):  # in blocks, so only one full-size copy exists
        r1 = min(r0 + rows, len(ys))
        unit[r0 * len(xs):r1 * len(xs)] = _gather_patches(feat, ys[r0:r1], xs, patch_size)
    norm = unit.norm(dim=1)
    unit.div_(norm.clamp_min(_EPS)[:, None])
    return StylePatches(unit=unit, norm=norm, channels=feat.shape[0], size=patch_size)


def _blocks(n_target: int, n_style: int, dim: int, chunk: int) -> tuple[int, int]:
    chunk = max(1, min(chunk, n_style))
    block = max(1, min(_SCORE_ELEMENTS // chunk, _BLOCK_ELEMENTS // dim, n_target))
    return block, chunk


class _PatchSSD(torch.autograd.Function):
    """Σ_p w(p)·(count(p)·‖x(p)‖² − 2·x(p)·R(p) + Q(p)) with its gradient 2w(count·x − R).

    Written as a Function so that no (C, H, W) temporaries are kept for backward; the value
    is accumulated in float64 over channel slices (x² − 2xR + Q cancels when matches are good)."""

    @staticmethod
    def forward(ctx, x, count, r_map, q_map, weight):
        ctx.save_for_backward(x, count, r_map, weight)
        total = (weight * q_map).double().sum()
        step = max(1, _BLOCK_ELEMENTS // 4 // max(1, x.shape[1] * x.shape[2]))
        for c0 in range(0, x.shape[0], step):
            xs, rs = x[c0:c0 + step].double(), r_map[c0:c0 + step].double()
            total += (weight.double() * (count.double() * xs.square() - 2.0 * xs * rs)).sum()
        return total.to(x.dtype)

    @staticmethod
    def backward(ctx, grad):
        x, count, r_map, weight = ctx.saved_tensors
        g = count * x  # in place from here: one (C, H, W) temporary
        g.sub_(r_map).mul_(weight).mul_(2.0 * grad)
        return g, None, None, None, None


def _best_style_patch(t: torch.Tensor, style: StylePatches, chunk: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(index, NCC × ‖target patch‖) of the most correlated style patch for each row of ``t``
    (n, C·k²), over the style patches in chunks of ``chunk`` (the same argmax as one product)."""
    best = torch.full((t.shape[0],), -torch.inf, dtype=t.dtype, device=t.device)
    idx = torch.zeros(t.shape[0], dtype=torch.long, device=t.device)
    for s0 in range(0, len(style), chunk):
        m, j = (t @ style.unit[s0:s0 + chunk].T).max(dim=1)
        better = m > best  # strict: the earlier chunk keeps ties, like a single argmax
        best = torch.where(better, m, best)
        idx = torch.where(better, j + s0, idx)
    return idx, best


def _match(feat: torch.Tensor, style: StylePatches, ys: torch.Tensor, xs: torch.Tensor, chunk: int,
           active: torch.Tensor | None = None):
    """Eq. 1: index of the most correlated style patch for each target patch, and its NCC.
    Patches where ``active`` (bool, n_t) is False are not matched (index 0, NCC NaN)."""
    n_t, n_s, dim = len(ys) * len(xs), len(style), style.unit.shape[1]
    block, chunk = _blocks(n_t, n_s, dim, chunk)
    rows_per_block = max(1, block // len(xs))
    best_idx = torch.empty(n_t, dtype=torch.long, device=feat.device)
    best_ncc = torch.empty(n_t, dtype=feat.dtype, device=feat.device)
    for r0 in range(0, len(ys), rows_per_block):
        r1 = min(r0 + rows_per_block, len(ys))
        sl = slice(r0 * len(xs), r1 * len(xs))
        t = _gather_patches(feat, ys[r0:r1], xs, style.size)
        rows = None
        if active is not None:
            rows = torch.nonzero(active[sl]).reshape(-1)
            best_idx[sl] = 0
            best_ncc[sl] = float("nan")
            if len(rows) == 0:
                continue
            t = t[rows]
        idx, best = _best_style_patch(t, style, chunk)
        ncc = best / t.norm(dim=1)  # NaN for an all-zero target patch, as in mrf.lua
        if rows is None:
            best_idx[sl] = idx
            best_ncc[sl] = ncc
        else:
            best_idx[sl][rows] = idx
            best_ncc[sl][rows] = ncc
    return best_idx, best_ncc


def _dense_maps(feat: torch.Tensor, style: StylePatches, chunk: int, active: torch.Tensor | None,
                threshold: float | None):
    """:func:`mrf_loss`'s matching and its count / R / Q maps for a stride-1 target grid in one
    piece: the target patches are one ``unfold`` (im2col) and the maps one ``fold`` (col2im)
    each, instead of per-block gathers and index-add scatters (the same sums; 2–3 times faster
    at the default preset's sizes). For maps up to :data:`_DENSE_ELEMENTS` patch elements."""
    import torch.nn.functional as F

    c, h, w = feat.shape
    k = style.size
    cols = F.unfold(feat[None], k)[0]  # (C·k², L), patches in row-major order of their origins
    n_t = cols.shape[1]
    rows = None if active is None else torch.nonzero(active).reshape(-1)
    t = cols.T if rows is None else cols.T.index_select(0, rows)  # (n, C·k²)
    n, n_s = t.shape[0], len(style)
    idx = torch.zeros(n, dtype=torch.long, device=feat.device)
    if n:
        step = max(1, min(_SCORE_ELEMENTS // max(1, min(chunk, n_s)), n))
        chunk = max(1, min(chunk, n_s))
        for t0 in range(0, n, step):
            tb = t[t0:t0 + step]
            bi, best = _best_style_patch(tb, style, chunk)
            idx[t0:t0 + step] = bi
            if threshold is not None:  # NaN for an all-zero patch (dropped), as in mrf.lua
                ncc = best / tb.norm(dim=1)
                bi_keep = ncc >= threshold
                idx[t0:t0 + step] = torch.where(bi_keep, bi, torch.full_like(bi, -1))
    keep_rows = torch.arange(n, device=feat.device) if rows is None else rows
    if threshold is not None:
        kept = idx >= 0
        keep_rows, idx = keep_rows[kept], idx[kept]
    matched = style.patches(idx)  # (n_kept, C·k²)
    full = torch.zeros(c * k * k + k * k + k * k, n_t, dtype=feat.dtype, device=feat.device)
    full[:c * k * k, keep_rows] = matched.T
    full[c * k * k:c * k * k + k * k, keep_rows] = 1.0
    full[c * k * k + k * k:, keep_rows] = matched.reshape(-1, c, k * k).square().sum(1).T
    r_map = F.fold(full[None, :c * k * k], (h, w), k)[0]
    count = F.fold(full[None, c * k * k:c * k * k + k * k], (h, w), k)[0]
    q_map = F.fold(full[None, c * k * k + k * k:], (h, w), k)[0]
    return count, r_map, q_map, int(len(keep_rows))


def _prepare(target_feat, style, patch_size, style_stride):
    feat = _as_chw(target_feat, "target_feat")
    if not isinstance(style, StylePatches):
        style = style_patches(style, patch_size, style_stride)
    if style.channels != feat.shape[0]:
        raise BadInputError(f"target has {feat.shape[0]} channels but the style patches have {style.channels}")
    if style.unit.dtype != feat.dtype:
        style = StylePatches(style.unit.to(feat.dtype), style.norm.to(feat.dtype), style.channels, style.size)
    return feat, style


def mrf_match(target_feat: torch.Tensor, style_feat: torch.Tensor | StylePatches, *, patch_size: int = 3,
              style_stride: int = 2, target_stride: int = 1, chunk: int = 1024,
              return_ncc: bool = False):
    """Eq. 1: for each target patch (origins on a ``target_stride`` grid), the index into
    ``extract_patches(style_feat, patch_size, style_stride)`` of the patch with the highest
    normalised cross-correlation. Returns a long tensor (rows, cols) of target origins
    (and the NCC, same shape, if ``return_ncc``)."""
    feat, style = _prepare(target_feat, style_feat, patch_size, style_stride)
    ys, xs = _grid(feat.shape[1], style.size, target_stride), _grid(feat.shape[2], style.size, target_stride)
    with torch.no_grad():
        idx, ncc = _match(feat.detach(), style, ys, xs, chunk)
    idx, ncc = idx.reshape(len(ys), len(xs)), ncc.reshape(len(ys), len(xs))
    return (idx, ncc) if return_ncc else idx


def mrf_loss(target_feat: torch.Tensor, style_feat: torch.Tensor | StylePatches, *, patch_size: int = 3,
             style_stride: int = 2, target_stride: int | None = None, chunk: int = 1024,
             reduction: str = "sum", variant: str = "paper", threshold: float | None = ...,
             matches: torch.Tensor | None = None, target_weight: torch.Tensor | None = None) -> torch.Tensor:
    """Eq. 2: Σ_i ‖Ψ_i(Φ(x_t)) − Ψ_NN(i)(Φ(x_s))‖² over the target patches.

    ``style_feat`` is a style feature map or :func:`style_patches` prepared once per level.
    ``variant`` "paper" (all patches, plain sum) or "reference" (CNNMRF: stride-2 target grid,
    coverage-averaged half sum, NCC threshold 0); ``target_stride`` / ``threshold`` override
    it. ``reduction`` "sum" or "mean" (over the kept target patches). ``matches`` (rows, cols),
    e.g. from :func:`mrf_match`, fixes the matching (for gradient checks). Matches are
    otherwise recomputed on every call; gradients flow only through ``target_feat``.
    ``target_weight`` (H, W) ≥ 0 weights each feature position's squared differences
    (beyond the paper: restricts the texture loss to the content's skin).
    """
    if variant not in MRF_VARIANTS:
        raise BadInputError(f"variant must be one of {sorted(MRF_VARIANTS)}, not {variant!r}")
    if reduction not in ("sum", "mean"):
        raise BadInputError(f"reduction must be 'sum' or 'mean', not {reduction!r}")
    cfg = MRF_VARIANTS[variant]
    target_stride = cfg["target_stride"] if target_stride is None else target_stride
    threshold = cfg["threshold"] if threshold is ... else threshold
    feat, style = _prepare(target_feat, style_feat, patch_size, style_stride)
    k, (c, h, w) = style.size, feat.shape
    ys, xs = _grid(h, k, target_stride), _grid(w, k, target_stride)
    tw = None
    if target_weight is not None:
        tw = torch.as_tensor(target_weight, dtype=feat.dtype, device=feat.device)
        if tw.numel() != h * w:
            raise BadInputError(f"target_weight must be ({h}, {w}), got {tuple(tw.shape)}")
        tw = tw.reshape(1, h, w)
    with torch.no_grad():
        fd = feat.detach()
        active = None
        if tw is not None:  # patches with no weighted position contribute nothing: skip them
            wmax = torch.nn.functional.max_pool2d(tw[None], k, stride=1)[0, 0]
            active = (wmax[ys][:, xs] > 0).reshape(-1)
        dense = matches is None and target_stride == 1 and c * k * k * len(ys) * len(xs) <= _DENSE_ELEMENTS
        if dense:
            count, r_map, q_map, n_kept = _dense_maps(fd, style, chunk, active, threshold)
        elif matches is None:
            idx, ncc = _match(fd, style, ys, xs, chunk, active)
        else:
            idx = matches.reshape(-1).to(feat.device)
            if idx.numel() != len(ys) * len(xs):
                raise BadInputError(f"matches has {idx.numel()} entries, expected {len(ys) * len(xs)}")
            ncc = None
            if threshold is not None:
                t = _gather_patches(fd, ys, xs, k)
                ncc = (t * style.unit[idx]).sum(1) / t.norm(dim=1)
        if not dense:
            keep = None if threshold is None else ncc >= threshold
            if active is not None:
                keep = active if keep is None else keep & active
            # Per-position coverage count, sum of matched values R and their squared norms Q.
            count = torch.zeros(1, h, w, dtype=feat.dtype, device=feat.device)
            r_map = torch.zeros(c, h, w, dtype=feat.dtype, device=feat.device)
            q_map = torch.zeros(1, h, w, dtype=feat.dtype, device=feat.device)
            rows = max(1, _BLOCK_ELEMENTS // (len(xs) * c * k * k))
            for r0 in range(0, len(ys), rows):
                r1 = min(r0 + rows, len(ys))
                sl = slice(r0 * len(xs), r1 * len(xs))
                s = style.patches(idx[sl])
                ones = torch.ones(s.shape[0], k * k, dtype=feat.dtype, device=feat.device)
                sq = s.reshape(s.shape[0], c, k * k).square().sum(1)
                if keep is not None:
                    kb = keep[sl].to(feat.dtype)[:, None]
                    s, ones, sq = s * kb, ones * kb, sq * kb
                _scatter_patches(r_map, s, ys[r0:r1], xs, k)
                _scatter_patches(count, ones, ys[r0:r1], xs, k)
                _scatter_patches(q_map, sq, ys[r0:r1], xs, k)
            n_kept = len(ys) * len(xs) if keep is None else int(keep.sum())
        weight = torch.ones_like(count) if cfg["weighting"] == "sum" else 0.5 / (count + 1e-10)
        if tw is not None:
            weight = weight * tw
    loss = _PatchSSD.apply(feat, count, r_map, q_map, weight)  # Eq. 2
    if reduction == "mean":
        loss = loss / max(n_kept, 1)
    return loss


class MRFLoss(nn.Module):
    """:func:`mrf_loss` against a fixed style feature map, its patches prepared once
    (rebuild per resolution level). Keyword arguments are those of :func:`mrf_loss`."""

    def __init__(self, style_feat: torch.Tensor, *, patch_size: int = 3, style_stride: int = 2, **kwargs):
        super().__init__()
        self.style = style_patches(style_feat, patch_size, style_stride)
        self.kwargs = kwargs

    def forward(self, target_feat: torch.Tensor) -> torch.Tensor:
        return mrf_loss(target_feat, self.style, **self.kwargs)


def mrf_memory_estimate(channels: int, target_hw: tuple[int, int], style_hw: tuple[int, int], *,
                        patch_size: int = 3, style_stride: int = 2, target_stride: int = 1,
                        chunk: int = 1024, bytes_per_element: int = 4) -> int:
    """Upper bound (bytes) of the extra memory one :func:`mrf_loss` call allocates."""
    k, d = patch_size, channels * patch_size**2
    n_s = len(_grid(style_hw[0], k, style_stride)) * len(_grid(style_hw[1], k, style_stride))
    n_t = len(_grid(target_hw[0], k, target_stride)) * len(_grid(target_hw[1], k, target_stride))
    h, w = target_hw
    elements = (n_s * (d + 1)  # unit style patches and norms
                + 4 * channels * h * w + 4 * h * w  # R, gradient (+ a copy through views), x slices; count, Q, w
                + 4 * _BLOCK_ELEMENTS + 2 * _SCORE_ELEMENTS  # target-patch block and copies; scores, max
                + 3 * n_t)  # indices (int64) and NCC
    return int(1.25 * bytes_per_element * elements)  # + allocator slack (measured RSS growth)


def channel_softmax(feat: torch.Tensor, temperature: float = 1.0) -> torch.Tensor:
    """SWAG's feature transform (Wang, Li & Vasconcelos, CVPR 2021): a softmax over the
    channels at every position, ``exp(f_c / T) / Σ_c' exp(f_c' / T)``. It flattens the peaky,
    low-entropy activations of residual networks, with which style losses stylise poorly,
    into distributions whose statistics behave like VGG's. Feature maps (C, H, W) or (N, C, H, W)."""
    if feat.ndim not in (3, 4):
        raise BadInputError(f"channel_softmax expects (C, H, W) or (N, C, H, W), got shape {tuple(feat.shape)}")
    return torch.softmax(feat / float(temperature), dim=-3)


def content_loss(a: torch.Tensor, b: torch.Tensor, reduction: str = "sum") -> torch.Tensor:
    """Squared L2 distance ‖a − b‖² of feature maps (Eq. 6 content term, a plain sum).

    ``reduction="mean"`` divides by the number of elements: CNNMRF's content.lua
    (``nn.MSECriterion``) and neural-style use the mean."""
    if a.shape != b.shape:
        raise BadInputError(f"content features differ in shape: {tuple(a.shape)} vs {tuple(b.shape)}")
    d = (a - b).square()
    if reduction == "sum":
        return d.sum()
    if reduction == "mean":
        return d.mean()
    raise BadInputError(f"reduction must be 'sum' or 'mean', not {reduction!r}")


def gram_matrix(feat: torch.Tensor, normalize: bool = True) -> torch.Tensor:
    """Gram matrix FFᵀ of (C, H, W) → (C, C) or (N, C, H, W) → (N, C, C); divided by C·H·W
    when ``normalize`` (neural-style / CNNMRF style.lua convention)."""
    if feat.ndim not in (3, 4):
        raise BadInputError(f"gram_matrix expects (C, H, W) or (N, C, H, W), got shape {tuple(feat.shape)}")
    f = feat.flatten(-2)
    g = f @ f.transpose(-1, -2)
    if normalize:
        g = g / (feat.shape[-3] * feat.shape[-2] * feat.shape[-1])
    return g


def gram_loss(a: torch.Tensor, b: torch.Tensor, normalize: bool = True, reduction: str = "sum") -> torch.Tensor:
    """Eq. 6 style term ‖G(a) − G(b)‖²_F. ``b`` is a feature map or a precomputed Gram matrix
    (one dimension fewer than ``a``). Gram normalised by C·H·W if ``normalize``;
    ``reduction="mean"`` averages over the C² entries (neural-style's MSECriterion)."""
    ga = gram_matrix(a, normalize)
    gb = b if b.ndim == a.ndim - 1 else gram_matrix(b, normalize)
    return content_loss(ga, gb.to(ga.dtype), reduction)


def structure_loss(feats_t: dict[str, torch.Tensor], feats_c: dict[str, torch.Tensor]) -> torch.Tensor:
    """Eq. 3: Σ_i ‖δ_i(x_t) − δ_i(x_c)‖² / (C_i H_i W_i) over the layers of ``feats_t``
    (the same as CNNMRF's MSE content loss on VGG-Face, summed over layers)."""
    if not feats_t:
        raise BadInputError("structure_loss needs at least one layer")
    missing = [k for k in feats_t if k not in feats_c]
    if missing:
        raise BadInputError(f"structure_loss: content features lack layer(s) {missing}")
    return sum(content_loss(feats_t[k], feats_c[k].to(feats_t[k].dtype), "mean") for k in feats_t)


def tv_loss(x: torch.Tensor, variant: str = "paper") -> torch.Tensor:
    """Eq. 4: Σ (x_{i,j+1} − x_{i,j})² + (x_{i+1,j} − x_{i,j})² over all channels and valid pairs.

    ``variant="reference"``: CNNMRF's tv.lua, whose gradient is that of half this sum
    restricted to the top-left (H−1)×(W−1) crop (one TV layer; the code has two)."""
    if x.ndim < 2:
        raise BadInputError(f"tv_loss expects an image tensor (..., H, W), got shape {tuple(x.shape)}")
    dx = x[..., :, 1:] - x[..., :, :-1]
    dy = x[..., 1:, :] - x[..., :-1, :]
    if variant == "paper":
        return dx.square().sum() + dy.square().sum()
    if variant == "reference":
        return 0.5 * (dx[..., :-1, :].square().sum() + dy[..., :, :-1].square().sum())
    raise BadInputError(f"variant must be 'paper' or 'reference', not {variant!r}")
