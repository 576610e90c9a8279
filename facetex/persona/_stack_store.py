"""The 8-bit storage of the persona's aligned photos in the .persona file: each aligned [image,
confidence] as 8-bit codes plus the image's packed 9th bits, the confidence on a logarithmic
scale; and the key (version and parameters) that stored stacks are valid for."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np

from .params import TextureParams

#: version of the stacks' computation: stored stacks of another version are recomputed
STACKS_VERSION = 1


def _conf_range(tp: TextureParams) -> tuple[float, float]:
    """(lo, hi) of the confidences' logarithmic 8-bit code: the floor and the largest confidence
    :func:`facetex.geometry.frontalize.fill_confidence` gives (values outside are clipped)."""
    lo = max(float(tp.visibility_floor), 1e-3) if tp.use_visibility else 0.5
    hi = (max(1.0, tp.mirror_weight) * max(1.0, tp.face_support) + max(tp.visibility_floor, 0.0)
          if tp.use_visibility else 2.0)
    return lo, max(hi, 2 * lo)


def _quantize_aligned(ic: np.ndarray, tp: TextureParams, out: np.ndarray | None = None,
                      lsb: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """An aligned (H, W, 4) float32 [image, confidence] quantized: ((H, W, 4) uint8 codes, (m,) uint8
    the image's 9th bits, packed). The image in 1/511 steps: the codes hold its top 8 bits, ``lsb``
    the last one (its max error 0.25/255 at all pyramid levels together, the pyramid being linear;
    8 bits gave 0.5/255 in the textures, which a composite's colour transfer amplified to 1.7/255
    for a dark-skinned persona). The confidence, a relative weight from the floor (0.02) to ~1, on
    a logarithmic 8-bit scale (0.8 % relative error; < 0.01/255 in the textures)."""
    lo, hi = _conf_range(tp)
    out = np.empty(ic.shape, np.uint8) if out is None else out
    q9 = np.rint(np.clip(ic[..., :3], 0, 1) * 511).astype(np.uint16)
    np.right_shift(q9, 1, out=out[..., :3], casting="unsafe")
    bits = np.zeros(ic.shape, np.uint8)
    np.bitwise_and(q9, 1, out=bits[..., :3], casting="unsafe")
    packed = np.packbits(bits.reshape(-1))
    if lsb is None:
        lsb = packed
    else:
        lsb[...] = packed
    c = np.log(np.clip(ic[..., 3], lo, hi) / lo) * (255 / math.log(hi / lo))
    np.rint(c, out=out[..., 3], casting="unsafe")
    return out, lsb


def _lsb_bytes(shape) -> int:
    """Bytes of one aligned photo's packed 9th bits (4 channels of ``shape`` (H, W))."""
    return -(-int(shape[0]) * int(shape[1]) * 4 // 8)


def _aligned_lut(tp: TextureParams) -> np.ndarray:
    """(1, 256, 4) float32 values of :func:`_quantize_aligned`'s codes without the 9th bit (``cv2.LUT``)."""
    lo, hi = _conf_range(tp)
    q = np.arange(256, dtype=np.float64)
    return np.stack([2 * q / 511, 2 * q / 511, 2 * q / 511, lo * (hi / lo) ** (q / 255)], axis=-1)[None].astype(np.float32)


def _lsb_lut() -> np.ndarray:
    """(1, 256, 4) float32: the value of a set 9th bit (1/511, none for the confidence)."""
    lut = np.zeros((1, 256, 4), np.float32)
    lut[0, 1, :3] = 1 / 511
    return lut


def _dequantize_aligned(q: np.ndarray, lsb: np.ndarray, luts: tuple, work: dict | None = None) -> np.ndarray:
    """(H, W, 4) float32 [image, confidence] of :func:`_quantize_aligned`'s (codes, 9th bits);
    ``luts`` = (:func:`_aligned_lut`, :func:`_lsb_lut`); ``work``: buffers reused between calls."""
    work = {} if work is None else work
    if work.get("ic") is None or work["ic"].shape != q.shape:
        work.update(ic=np.empty(q.shape, np.float32), bits=np.empty(q.shape, np.float32))
    ic = cv2.LUT(q, luts[0], dst=work["ic"])
    bits = np.unpackbits(lsb, count=q.size).reshape(q.shape)
    return cv2.add(ic, cv2.LUT(bits, luts[1], dst=work["bits"]), dst=ic)


def _stored_key(tp: TextureParams) -> list:
    """JSON form of what stored stacks depend on (compared with a .persona's header)."""
    return json.loads(json.dumps([STACKS_VERSION, *tp.stack_key()]))


def stale_stacks(stored: dict | None) -> bool:
    """Whether a .persona's stored stacks were made with another stack key than the default
    parameters' (an earlier facetex): a load recomputes them, a save makes them again."""
    return bool(stored) and stored["meta"].get("key") != _stored_key(TextureParams())


def warn_stale_stacks(stored: dict | None, tp: TextureParams) -> None:
    """Warn (naming the file) when ``tp`` has the default stack key and the stored stacks are
    :func:`stale_stacks`: they are then recomputed at every load."""
    if _stored_key(tp) != _stored_key(TextureParams()) or not stale_stacks(stored):
        return
    import warnings

    warnings.warn(f"{stored.get('path') or 'persona'}: its texture stacks were made with other settings (an "
                  "earlier facetex): recomputed at every load (seconds for hundreds of photos); rebuild it with "
                  "`facetex persona build`, or save it again (facetex.persona.load_persona(path).save(path, "
                  "overwrite=True)), to store them", stacklevel=3)


#: a photo without a gaze score as a .persona stores it (scores lie in [-1, 1])
NO_GAZE = -9.0


def store_photo_scores(arrays: dict, meta: dict, gaze: np.ndarray, band_energy: np.ndarray) -> None:
    """Add the photos' gaze scores (n,) and band energies (levels, regions, n), made from the same
    stacks a load rebuilds, to a .persona's stored ``arrays`` and ``meta``: a load then does not
    compute them (~0.45 s of CPU of a 519-photo persona)."""
    arrays["texture_gaze"] = np.where(np.isfinite(gaze), gaze, NO_GAZE)
    meta["gaze"] = True
    arrays["texture_band_energy"] = np.asarray(band_energy, np.float64)
    meta["band_energy"] = list(arrays["texture_band_energy"].shape[:2])


def stored_photo_scores(stored: dict, energy_shape: tuple) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(gaze (n,) float64 with NaN for none, band energy of ``energy_shape``) as a .persona stored
    them (:func:`store_photo_scores`); None for what it does not hold or holds in another shape."""
    arrays, meta = stored["arrays"], stored["meta"]
    gaze = arrays.get("texture_gaze") if meta.get("gaze") else None
    if gaze is not None and gaze.shape == energy_shape[-1:]:
        gaze = np.where(gaze >= -1, gaze, np.nan).astype(np.float64)
    else:
        gaze = None
    energy = arrays.get("texture_band_energy")
    energy = np.asarray(energy, np.float64) if energy is not None and energy.shape == tuple(energy_shape) else None
    return gaze, energy
