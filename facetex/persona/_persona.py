"""The :class:`Persona` object: a person's frontalized, aligned photo collection with its
parameters, saved as a ``.persona`` file (an ``.npz`` zip with a JSON header); members of
version-4 files are held packed and unpacked on first use."""

from __future__ import annotations

import json
import struct
import tokenize
import zipfile
import zlib
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .._parallel import available_cpus
from ..errors import BadPersonaError
from ._packed import Packed

PERSONA_FORMAT = "facetex-persona"
PERSONA_VERSION = 4
IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")


@dataclass(frozen=True)
class PersonaParams:
    """Build parameters (Tom Hanks Sec. 5/6 where the paper gives them).

    size: canonical frame (W, H) (the paper's face is ~194 x 244);
    tps_smoothing: lambda of Eq. 1; flow_alpha: dense-warp optical-flow alpha;
    subspace_rank: principal components besides the mean; max_yaw: |yaw| (deg) above
    which a photo is skipped; dominant_ratio: a second face larger than this fraction
    of the largest makes the photo ambiguous; min_photos: fewest usable photos;
    flow_method: see :func:`facetex.geometry.flow.optical_flow`; shape_photos: at most this
    many evenly spaced photos feed the photometric stereo of the average 3D face (its SVD
    grows with the square of the count; a few dozen lightings fix the rank-4 factorization);
    landmark_face_px, landmark_refits: a photo's landmarks are fitted as the driver's tracker fits a
    frame's (:func:`facetex._landmark_fit.refine_landmarks`: upscaled when the face box is narrower
    than landmark_face_px, fitted again landmark_refits times in the box the points carry; not the
    tracker's dark-face mouth refit at a normalised exposure; landmark_face_px 0: dlib's points at
    the photo's size, as files written before it were built). Leave-out mouth SSIM over static (5 folds), dlib's points ->
    these: Bush +0.0406 -> +0.0431, Blair +0.0531 -> +0.0522, Williams +0.0543 -> +0.0554, Chavez
    +0.0463 -> +0.0495, Koizumi +0.0294 -> +0.0334, Arroyo +0.0357 -> +0.0363; with the dark-face mouth
    refit too, Williams +0.0508 (dropped). landmark_mirror: the fit repeated on the mirror image and
    the two averaged (:func:`facetex._landmark_fit.refine_landmarks`; only with landmark_face_px > 0;
    files written before it: False): leave-out SSIM over static, 5 folds, paired per target, mouth
    Koizumi +0.0334 -> +0.0335, Arroyo +0.0363 -> +0.0379, Blair +0.0522 -> +0.0545, Williams
    +0.0554 -> +0.0559, Chavez +0.0495 -> +0.0506; face +0.0042 +- 0.0023, +0.0022 +- 0.0012, +0.0032
    +- 0.0009, +0.0006, +0.0004 (eyes +0.008, +0.003, +0.004, -0.001, -0.003, within 1 s.e.).
    """

    size: tuple[int, int] = (192, 240)
    tps_smoothing: float = 10.0
    flow_alpha: float = 0.3
    subspace_rank: int = 4
    max_yaw: float = 45.0
    dominant_ratio: float = 0.8
    min_photos: int = 10
    flow_method: str = "variational"
    shape_photos: int = 128
    landmark_face_px: float = 200.0
    landmark_refits: int = 1
    landmark_mirror: bool = True


@dataclass(eq=False)
class Persona:
    """A built persona. Arrays (n photos, canonical H x W):

    images (n, H, W, 3) uint8 frontalized photos; visibility (n, H, W) uint8 (x 255);
    fiducials (n, 49, 2) float64 pose-corrected F^i; points68 (n, 68, 2) float64
    (pose-corrected, for masks); poses (n, 3) float64 yaw, pitch, roll in degrees;
    flows (n, H, W, 2) float16 collection flow in the neutral frame (from the projection
    to the TPS-warped photo), in 1/256 px (:func:`quantize_flow`); subspace (1 + rank, H, W, 3)
    float32 (float16 values) mean and orthonormal (inside the face mask) principal components of
    the TPS-warped photos.
    ``photos``: file names; ``skipped``: [{"file", "reason"}].
    depth (H, W) float32: the raw photometric-stereo average depth (canonical px, NaN off
    the face region; all NaN when the reconstruction failed) or None (version-1 file, not
    computed); depth_photos: photos that fed it (0 when it failed or is absent).
    texture_stacks: {"meta", "arrays"} as read from a version-3 or 4 file (or None): the texture
    synthesis's precomputed stacks (version 4: what they are rebuilt from), handed to it on first use.
    Read from a version-4 file, images, visibility and flows are unpacked on first use.
    """

    images: np.ndarray = field(repr=False)
    visibility: np.ndarray = field(repr=False)
    fiducials: np.ndarray
    points68: np.ndarray
    poses: np.ndarray
    flows: np.ndarray = field(repr=False)
    subspace: np.ndarray
    photos: list[str]
    skipped: list[dict] = field(default_factory=list)
    params: PersonaParams = field(default_factory=PersonaParams)
    source: str = ""
    depth: np.ndarray | None = None
    depth_photos: int = 0
    shape_report: dict | None = None
    texture_stacks: dict | None = field(default=None, repr=False)
    _cache: dict = field(default_factory=dict, repr=False)

    def __len__(self) -> int:
        return len(self.fiducials)

    @property
    def size(self) -> tuple[int, int]:
        """Canonical frame (W, H)."""
        shape = _lazy_shape(self, "images")
        return int(shape[2]), int(shape[1])

    def image(self, i: int) -> np.ndarray:
        """Photo i's frontalized image (H, W, 3) uint8, unpacked alone while the stack is packed
        (a version-4 file's whole stack takes ~0.6 s for 500 photos)."""
        v = self.__dict__["_images"]
        return v.photo(i) if isinstance(v, _Lazy) else v[i]

    @property
    def mean_fiducials(self) -> np.ndarray:
        """M: the collection's mean pose-corrected fiducials, the neutral frame (49, 2)."""
        return self.fiducials.mean(axis=0)

    def header(self) -> dict:
        return {
            "format": PERSONA_FORMAT,
            "version": PERSONA_VERSION,
            "parameters": {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self.params).items()},
            "source": self.source,
            "photos": [
                {"file": f, "yaw": float(p[0]), "pitch": float(p[1]), "roll": float(p[2])}
                for f, p in zip(self.photos, self.poses)
            ],
            "skipped": list(self.skipped),
            # None: no depth array stored
            "depth_photos": None if self.depth is None else int(self.depth_photos),
            "shape": self.shape_report,
        }

    def save(self, path, *, overwrite: bool = False, texture_stacks: bool = True) -> Path:
        """Write the persona atomically as one ``.persona`` file (npz zip + JSON header).

        ``texture_stacks``: also store what the texture synthesis's precomputed stacks are rebuilt
        from (~60 kB per photo; computed now if needed, or if the file's were made with other
        settings): puppetry and texture synthesis then start without aligning every photo again."""
        from ..io import atomic_path, check_output_path

        path = check_output_path(path, overwrite=overwrite)
        header = self.header()
        arrays = {k: getattr(self, k) for k in _ARRAYS if k not in _PACKED}
        arrays["subspace"] = np.asarray(self.subspace).astype(np.float16)  # build rounds it so (SUBSPACE_DTYPE)
        arrays.update({k: _packed_member(self, k) for k in _PACKED})
        if self.depth is not None:
            arrays["depth"] = np.asarray(self.depth, np.float32)
        stacks = None
        if texture_stacks:
            from ._stack_store import stale_stacks
            from .stacks import stored_stacks

            if stale_stacks(self.texture_stacks):
                self.texture_stacks = None  # made with other settings (an earlier facetex): made again now
            stacks = self.texture_stacks if _packed_stacks(self.texture_stacks) else stored_stacks(self)
            arrays.update(sorted(stacks["arrays"].items()))  # one member order, computed or as read
        members = {}
        for name, arr in arrays.items():
            if isinstance(arr, Packed):
                members[name], members[f"{name}_offsets"] = arr.blob, arr.offsets
            else:
                members[name] = arr

        def write(z, name, arr):
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            stored = name in _STORED or name.startswith("texture_")
            info.compress_type = zipfile.ZIP_STORED if stored else zipfile.ZIP_DEFLATED
            with z.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.ascontiguousarray(arr), allow_pickle=False)

        with atomic_path(path, overwrite=overwrite) as tmp:
            with open(tmp, "wb") as fh, zipfile.ZipFile(fh, "w", allowZip64=True) as z:
                for name, arr in members.items():
                    write(z, name, arr)
                if stacks is not None:  # the header comes last: it names the CRC-32s just written
                    crcs = {f"{k}.npy": z.getinfo(f"{k}.npy").CRC for k in _STACK_SOURCES if k in members}
                    header["texture_stacks"] = {**stacks["meta"], "sources_crc32": stacks["meta"].get(
                        "sources_crc32", crcs)}  # as read: the members they were made from
                write(z, "header", np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8))
        return path


def _packed_member(persona: Persona, name: str) -> Packed:
    """images / visibility / flows packed for a version-4 file (as read, when not unpacked since)."""
    v = persona.__dict__[f"_{name}"]
    if isinstance(v, _Lazy):
        return v.packed
    if name == "flows":
        v = np.clip(np.rint(np.asarray(v, np.float32) * 256), -32767, 32767).astype(np.int16)
    return Packed.pack(v, workers=available_cpus())


def _packed_stacks(stacks: dict | None) -> bool:
    """Whether ``stacks`` (Persona.texture_stacks) are of the version-4 kind (packed aligned photos)."""
    return bool(stacks) and "aligned" in stacks["meta"]


class _Lazy:
    """A packed member of a version-4 file, unpacked on first use."""

    __slots__ = ("packed", "path", "name")

    def __init__(self, packed: Packed, path: Path, name: str):
        self.packed, self.path, self.name = packed, path, name

    def photo(self, i: int) -> np.ndarray:
        try:
            return self.packed.photo(i)
        except _CORRUPT as e:
            raise _bad(self.path, f"corrupt persona file ({self.name}, photo {i}: {type(e).__name__}: {e})") from None

    def value(self) -> np.ndarray:
        try:
            a = self.packed.unpack(workers=available_cpus())
        except _CORRUPT as e:
            raise _bad(self.path, f"corrupt persona file ({self.name}: {type(e).__name__}: {e})") from None
        return (a * np.float32(1 / 256)).astype(np.float16) if self.name == "flows" else a


def _lazy_array(name: str) -> property:
    key = f"_{name}"

    def get(self):
        v = self.__dict__[key]
        if isinstance(v, _Lazy):
            v = self.__dict__[key] = v.value()
        return v

    def put(self, value):
        self.__dict__[key] = value

    return property(get, put, doc=f"{name} (unpacked from a version-4 file on first use)")


def _lazy_shape(persona: Persona, name: str) -> tuple[int, ...]:
    v = persona.__dict__[f"_{name}"]
    return v.packed.shape if isinstance(v, _Lazy) else np.shape(v)


#: precision of the appearance subspace in version-4 files (and of a build's): it only feeds the
#: least-squares projection of a reference photo (half the 2.8 MB of float32)
SUBSPACE_DTYPE = np.float16

#: members of version-4 files packed losslessly (flows in 1/256 px as int16) and unpacked on first use
_PACKED = {"images": np.uint8, "visibility": np.uint8, "flows": np.int16}
for _name in _PACKED:
    setattr(Persona, _name, _lazy_array(_name))


#: members the texture stacks are made from: a header with stacks names their zip CRC-32s
#: ("sources_crc32"); a file whose photos were replaced but not its stacks recomputes them
_STACK_SOURCES = ("images", "images_offsets", "visibility", "visibility_offsets", "flows", "flows_offsets",
                  "fiducials", "points68")

#: members written uncompressed (an npz is a zip: np.load reads both kinds). Deflate saved
#: 20-27 % of the raw images and flows of version-3 files but cost 1.7 s of every load of a
#: 519-photo persona (measured); packed members and the texture stacks (texture_*) are stored too.
_STORED = ("images", "flows", "visibility", "images_offsets", "flows_offsets", "visibility_offsets")


# name -> (dtype, trailing shape given (n, H, W, rank)) of the stored arrays
_ARRAYS = {
    "images": (np.uint8, lambda n, H, W, r: (n, H, W, 3)),
    "visibility": (np.uint8, lambda n, H, W, r: (n, H, W)),
    "fiducials": (np.float64, lambda n, H, W, r: (n, 49, 2)),
    "points68": (np.float64, lambda n, H, W, r: (n, 68, 2)),
    "poses": (np.float64, lambda n, H, W, r: (n, 3)),
    "flows": (np.float16, lambda n, H, W, r: (n, H, W, 2)),
    "subspace": (np.float32, lambda n, H, W, r: (r + 1, H, W, 3)),
}


#: what a damaged zip member can raise while being read (zlib, npy header parsing, zip checks)
_CORRUPT = (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, OSError, EOFError, KeyError, UnicodeDecodeError,
            SyntaxError, tokenize.TokenError, zlib.error, struct.error, OverflowError, NotImplementedError,
            TypeError, IndexError)


def _bad(path, what: str) -> BadPersonaError:
    return BadPersonaError(f"{what}: rebuild it with `facetex persona build`", path=path)
