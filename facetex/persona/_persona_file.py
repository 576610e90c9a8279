"""Reading ``.persona`` files: the JSON header checked against its schema and every member's
declared type and shape before any array is read (pickles are never loaded), then the arrays'
ranges and the memory they need."""

from __future__ import annotations

import hashlib
import json
import struct
import zipfile
from pathlib import Path

import numpy as np

from .._schema import check_shape
from ..errors import BadPersonaError, PersonaNotFoundError
from ._packed import Packed, fast_zlib
from ._persona import (
    _ARRAYS,
    _CORRUPT,
    _PACKED,
    _STACK_SOURCES,
    PERSONA_FORMAT,
    PERSONA_VERSION,
    SUBSPACE_DTYPE,
    Persona,
    PersonaParams,
    _bad,
    _Lazy,
)

_MAX_HEADER_BYTES = 64 * 2**20


_NUMBER = {"type": "number"}
#: what a header must hold (the texture stacks' description is checked by _stack_members); the
#: parameters' ranges are generous: they only keep a crafted value from failing deep in a build
_HEADER_SCHEMA = {
    "type": "object",
    "required": ["parameters", "photos"],
    "properties": {
        "parameters": {
            "type": "object", "required": ["size"], "additionalProperties": False,
            "properties": {
                "size": {"type": "array", "minItems": 2, "maxItems": 2,
                         "items": {"type": "integer", "minimum": 1, "maximum": 4096}},
                "tps_smoothing": {"type": "number", "minimum": 0, "maximum": 1e6},
                "flow_alpha": {"type": "number", "exclusiveMinimum": 0, "maximum": 1e6},
                "subspace_rank": {"type": "integer", "minimum": 0, "maximum": 64},
                "max_yaw": {"type": "number", "minimum": 0, "maximum": 180},
                "dominant_ratio": {"type": "number", "minimum": 0, "maximum": 1},
                "min_photos": {"type": "integer", "minimum": 1},
                "flow_method": {"enum": ["variational", "dis", "dis_fast", "farneback"]},
                "shape_photos": {"type": "integer", "minimum": 1},
                "landmark_face_px": {"type": "number", "minimum": 0, "maximum": 4096},
                "landmark_refits": {"type": "integer", "minimum": 0, "maximum": 8},
                "landmark_mirror": {"type": "boolean"},
            },
        },
        "source": {"type": "string"},
        "photos": {"type": "array", "items": {
            "type": "object", "required": ["file"],
            "properties": {"file": {"type": "string"}, "yaw": _NUMBER, "pitch": _NUMBER, "roll": _NUMBER}}},
        "skipped": {"type": "array", "items": {"type": "object"}},
        "depth_photos": {"type": ["integer", "null"], "minimum": 0},
        "shape": {"type": ["object", "null"]},
        "texture_stacks": {"type": ["object", "null"]},
    },
}


#: digests of the header members that passed the schema check (the check is a function of them)
_CHECKED_HEADERS: set[bytes] = set()


def _read_header(path: Path) -> tuple[dict, PersonaParams, list[str]]:
    """Parse and validate only the JSON header member (no array is decompressed)."""
    from ..io import check_input_file

    if not path.exists() and not path.is_symlink():  # also a FileNotFoundError, as users catch it
        raise PersonaNotFoundError("persona file not found: build one with `facetex persona build`", path=path)
    check_input_file(path, BadPersonaError, what="persona file")  # FIFO, device, symlink loop, empty
    try:
        with zipfile.ZipFile(path) as zf:
            if "header.npy" not in zf.namelist():
                raise _bad(path, "not a persona file (no header)")
            locked = [i.filename for i in zf.infolist() if i.flag_bits & 0x1]
            if locked:  # zipfile would ask for a password (RuntimeError); facetex never writes them
                raise _bad(path, f"corrupt persona file (member {locked[0]!r} is encrypted)")
            if zf.getinfo("header.npy").file_size > _MAX_HEADER_BYTES:
                raise _bad(path, f"corrupt persona file (header member of {zf.getinfo('header.npy').file_size} "
                                 "bytes)")
            with zf.open("header.npy") as fh:
                raw = np.lib.format.read_array(fh, allow_pickle=False)
        header = json.loads(raw.tobytes().decode("utf-8"))
    except BadPersonaError:
        raise
    except RecursionError:
        raise _bad(path, "corrupt persona header (JSON nested too deeply)") from None
    except _CORRUPT as e:
        raise _bad(path, f"corrupt persona file ({type(e).__name__}: {e})") from None
    if not isinstance(header, dict) or header.get("format") != PERSONA_FORMAT:
        raise _bad(path, "not a persona file (unknown format)")
    version = header.get("version")
    if not isinstance(version, int) or isinstance(version, bool):  # true is no version 1
        raise _bad(path, f"corrupt persona header (version must be an integer, not {json.dumps(version)[:40]})")
    if version > PERSONA_VERSION or version < 1:
        raise BadPersonaError(
            f"persona format version {version!r} is not supported (this facetex reads up to "
            f"{PERSONA_VERSION}): upgrade facetex or rebuild the persona", path=path)
    # a header is checked once a process: `facetex puppet` reads it three times (a fail-fast check,
    # the canonical frame, the load), and the schema check of a 519-photo header takes ~0.1 s
    digest = hashlib.sha256(raw.tobytes()).digest()
    if digest not in _CHECKED_HEADERS:
        check_shape(header, _HEADER_SCHEMA, path=path, what="persona header", lead="corrupt persona header",
                    error=BadPersonaError, advice="rebuild it with `facetex persona build`")
        _CHECKED_HEADERS.add(digest)
    try:
        p = header["parameters"]
        # a file written before landmark_face_px was built from dlib's points as they are (0)
        # (and before landmark_mirror without the mirror fit)
        params = PersonaParams(**{"landmark_face_px": 0.0, "landmark_refits": 0, "landmark_mirror": False, **p,
                                  "size": tuple(int(v) for v in p["size"])})
        photos = [ph["file"] for ph in header["photos"]]
        _stack_members(header, len(photos), params.size)  # checks the stacks' description
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as e:
        raise _bad(path, f"corrupt persona header ({type(e).__name__}: {e})") from None
    return header, params, photos


def _stack_members(header: dict, n: int, size=(0, 0)) -> tuple[dict, dict]:
    """(plain, packed) name -> (dtype, shape) of the texture stacks a header declares (version 3:
    float16 stacks and float32 static sums; version 4: the packed aligned photos, (n, H, W, 4)
    uint8, ``size`` = (W, H)); ValueError for a malformed description."""
    meta = header.get("texture_stacks") if header.get("version", 0) >= 3 else None
    if meta is None:
        return {}, {}
    if not isinstance(meta, dict) or not isinstance(meta.get("key"), list):
        raise ValueError("texture_stacks")
    crcs = meta.get("sources_crc32", {})
    if not (isinstance(crcs, dict) and all(isinstance(v, int) and not isinstance(v, bool) for v in crcs.values())):
        raise ValueError("texture_stacks.sources_crc32")
    static = meta.get("static")
    if not (isinstance(static, list) and len(static) <= 32
            and all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 2**26 for v in static)):
        raise ValueError("texture_stacks")
    out = {f"texture_static_{k}": (np.float32, (m,)) for k, m in enumerate(static)}
    if meta.get("glasses") is True:  # each photo's eyeglasses score (-1: none), made with the stacks
        out["texture_glasses_scores"] = (np.float64, (n,))
    if meta.get("gaze") is True:  # each photo's gaze asymmetry (< -1: none), made with the stacks
        out["texture_gaze"] = (np.float64, (n,))
    energy = meta.get("band_energy")
    if energy is not None:  # each photo's band energy per (level, region): (levels, regions)
        if not (isinstance(energy, list) and len(energy) == 2 and energy[0] == len(static)
                and all(isinstance(v, int) and not isinstance(v, bool) and 0 < v <= 32 for v in energy)):
            raise ValueError("texture_stacks.band_energy")
        out["texture_band_energy"] = (np.float64, (energy[0], energy[1], n))
    if header["version"] >= 4:
        aligned = meta.get("aligned")
        rng = aligned.get("conf_range") if isinstance(aligned, dict) else None
        ok = (isinstance(rng, list) and len(rng) == 2 and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                               for v in rng) and 0 < rng[0] < rng[1] < 1e6)
        if not ok:
            raise ValueError("texture_stacks")
        W, H = size
        out["texture_aligned_lsb"] = (np.uint8, (n, -(-H * W * 4 // 8)))
        return out, {"texture_aligned": (np.uint8, (n, H, W, 4))}
    cols = meta.get("columns")
    ok = (isinstance(cols, list) and len(cols) == len(static)
          and all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 2**26 for v in cols))
    if not ok:
        raise ValueError("texture_stacks")
    out.update({f"texture_stack_{k}": (np.float16, (n, c)) for k, c in enumerate(cols)})
    return out, {}


def _member_specs(header: dict, params: PersonaParams, n: int) -> tuple[dict, dict]:
    """(plain, packed) name -> (dtype, shape) of the arrays a (validated) header implies; a packed
    member X is stored as X (its streams) and X_offsets (:class:`facetex.persona._packed.Packed`)."""
    W, H = params.size
    shapes = {k: (dtype, shape(n, H, W, params.subspace_rank)) for k, (dtype, shape) in _ARRAYS.items()}
    packed = {}
    if header["version"] >= 4:
        packed = {k: (dtype, shapes.pop(k)[1]) for k, dtype in _PACKED.items()}
        shapes["subspace"] = (SUBSPACE_DTYPE, shapes["subspace"][1])
    if header["version"] >= 2 and header.get("depth_photos") is not None:
        shapes["depth"] = (np.float32, (H, W))
    plain_stacks, packed_stacks = _stack_members(header, n, (W, H))
    return {**shapes, **plain_stacks}, {**packed, **packed_stacks}


def read_persona_header(path) -> dict:
    """The JSON header of a ``.persona`` file plus ``"size"`` (W, H) and ``"n_photos"``, without
    reading its arrays (cheap: for listings and checks). Same errors as :func:`load_persona`
    for missing, corrupt, foreign or too-new files."""
    from ..io import as_path

    header, params, photos = _read_header(as_path(path, BadPersonaError, "persona file"))
    return {**header, "size": tuple(params.size), "n_photos": len(photos)}


def load_persona(path) -> Persona:
    """Read a ``.persona`` file; BadPersonaError naming it if corrupt, of another format
    or version, or with inconsistent arrays. Version-1 files have no depth (``depth=None``).
    Version-4 files' images, visibility and flows are unpacked on first use (a corrupt stream
    then raises BadPersonaError naming the file; every member's CRC-32 is checked here)."""
    path = Path(path)
    header, params, photos = _read_header(path)
    version = header["version"]
    depth_photos = header.get("depth_photos") if version >= 2 else None
    n = len(photos)
    plain, packed = _member_specs(header, params, n)
    names = list(plain) + [m for k in packed for m in (k, f"{k}_offsets")]
    _check_members(path, header, params, photos)  # declared sizes and shapes, before decompressing
    try:
        with zipfile.ZipFile(path) as zf, open(path, "rb") as raw:
            files = {i.filename[:-4]: i for i in zf.infolist() if i.filename.endswith(".npy")}
            missing = [k for k in names if k not in files]
            if missing:
                raise _bad(path, f"persona file lacks arrays {missing}")
            arrays = {k: _read_stored(raw, files[k]) if files[k].compress_type == zipfile.ZIP_STORED
                      else _read_member(zf, files[k]) for k in names}
            crcs = {f"{k}.npy": files[k].CRC for k in _STACK_SOURCES if k in files}  # checked as read
        bad = [k for k, a in arrays.items() if not isinstance(a, np.ndarray)]  # npz members that are not .npy
        if bad:
            raise _bad(path, f"corrupt persona file (members {bad} are not arrays)")
    except BadPersonaError:
        raise
    except _CORRUPT as e:
        raise _bad(path, f"corrupt persona file ({type(e).__name__}: {e})") from None
    try:
        skipped = list(header.get("skipped", []))
    except TypeError as e:
        raise _bad(path, f"corrupt persona header ({type(e).__name__}: {e})") from None
    for k, (dtype, want) in plain.items():
        a = arrays[k]
        if a.dtype != dtype or a.shape != want:
            raise _bad(path, f"array {k!r} has {a.dtype} {a.shape}, expected {np.dtype(dtype)} {want}")
    packs = {}
    for k, (dtype, shape) in packed.items():
        blob, offsets = arrays.pop(k), arrays.pop(f"{k}_offsets")
        if blob.dtype != np.uint8 or blob.ndim != 1 or offsets.dtype != np.int64 or offsets.shape != (n + 1,):
            raise _bad(path, f"packed array {k!r} has {blob.dtype} {blob.shape} with {offsets.dtype} "
                             f"{offsets.shape} offsets, expected uint8 (m,) with int64 ({n + 1},)")
        try:
            packs[k] = Packed(blob, offsets, shape, dtype)
        except ValueError as e:
            raise _bad(path, f"corrupt persona file (packed array {k!r}: {e})") from None
    finite = ("fiducials", "points68", "poses", "subspace") + (("flows",) if version < 4 else ())
    if not all(_all_finite(arrays[k]) for k in finite):
        raise _bad(path, "persona arrays contain NaN or infinite values")
    _check_ranges(path, arrays, params.size)
    arrays["subspace"] = arrays["subspace"].astype(np.float32)
    if depth_photos is not None and np.isinf(arrays["depth"]).any():
        raise _bad(path, "persona depth contains infinite values")
    shape_report = header.get("shape") if version >= 2 else None
    if shape_report is not None and not isinstance(shape_report, dict):
        raise _bad(path, "corrupt persona header (shape report is not an object)")
    stacks = None
    made_from = (header.get("texture_stacks") or {}).get("sources_crc32")
    if made_from is not None and made_from != crcs:  # the photos were replaced, not the stacks
        import warnings

        changed = sorted(set(made_from.items()) ^ set(crcs.items()))[0][0]
        warnings.warn(f"{path}: its texture stacks were made from other photos ({changed} changed): "
                      "recomputed (save the persona again to store them)", stacklevel=2)
        for k in [k for k in plain if k.startswith("texture_")]:
            arrays.pop(k)
        packs.pop("texture_aligned", None)
    elif header.get("texture_stacks") is not None:  # version 3: float16 stacks; 4: packed aligned photos
        names = [k for k in plain if k.startswith("texture_")]
        if not all(_all_finite(arrays[k]) for k in names):
            raise _bad(path, "persona texture stacks contain NaN or infinite values")
        stacks = {"meta": dict(header["texture_stacks"]), "arrays": {k: arrays.pop(k) for k in names}, "path": str(path)}
        if "texture_aligned" in packs:
            stacks["arrays"]["texture_aligned"] = packs.pop("texture_aligned")
    arrays.update({k: _Lazy(v, path, k) for k, v in packs.items()})
    return Persona(photos=photos, skipped=skipped, params=params, source=str(header.get("source", "")),
                   depth_photos=int(depth_photos or 0), shape_report=shape_report, texture_stacks=stacks,
                   **arrays)


def _read_member(zf: zipfile.ZipFile, info: zipfile.ZipInfo) -> np.ndarray:
    with zf.open(info) as fh:
        return np.lib.format.read_array(fh, allow_pickle=False)


def _read_stored(raw, info: zipfile.ZipInfo) -> np.ndarray:
    """An uncompressed .npy member read straight into its array (one copy; file reads and the
    CRC check release the GIL, so a load overlaps other work): the zip's CRC-32 is checked."""
    from ..io import read_npy_header

    raw.seek(info.header_offset)
    local = raw.read(30)
    if len(local) != 30 or local[:4] != b"PK\x03\x04":
        raise zipfile.BadZipFile(f"bad local header of {info.filename}")
    name_len, extra_len = struct.unpack("<HH", local[26:30])
    start = info.header_offset + 30 + name_len + extra_len
    raw.seek(start)
    shape, fortran, dtype = read_npy_header(raw)
    if dtype.hasobject:
        raise ValueError(f"member {info.filename} holds Python objects")
    head = raw.tell() - start
    arr = np.empty(shape, dtype, order="F" if fortran else "C")
    buf = memoryview(arr.reshape(-1, order="A")).cast("B") if arr.size else memoryview(b"")
    if head + buf.nbytes != info.file_size or raw.readinto(buf) != buf.nbytes:
        raise EOFError(f"member {info.filename} is truncated")
    raw.seek(start)
    crc = fast_zlib.crc32(buf, fast_zlib.crc32(raw.read(head)))  # ISA-L's: 5x zlib's (~40 ms of a 97 MB load)
    if crc != info.CRC:
        raise zipfile.BadZipFile(f"bad CRC-32 for {info.filename}")
    return arr


def _check_ranges(path: Path, arrays: dict, size) -> None:
    """Refuse absurd (finite) values: landmarks far off the canonical frame (in canonical px, at
    most one frame's side beyond it) or head angles beyond 180 degrees."""
    side = float(max(size))
    limits = {"fiducials": (-side, 2 * side), "points68": (-side, 2 * side), "poses": (-180.0, 180.0)}
    for name, (lo, hi) in limits.items():
        a = arrays[name]
        if a.size and not (lo <= a.min() and a.max() <= hi):
            worst = a.min() if a.min() < lo else a.max()
            raise _bad(path, f"corrupt persona file (array {name!r} holds {worst:.4g}, outside [{lo:g}, {hi:g}])")


def _all_finite(a: np.ndarray) -> bool:
    if a.dtype == np.float16:  # exponent bits all set = inf or NaN (an integer test: no float conversion),
        bits = np.ascontiguousarray(a).reshape(-1).view(np.uint16)  # in cache-sized chunks (4x faster)
        return all(int((bits[i:i + 2**18] & 0x7C00).max()) != 0x7C00 for i in range(0, bits.size, 2**18))
    return bool(np.all(np.isfinite(a)))


def _check_members(path: Path, header: dict, params: PersonaParams, photos: list) -> None:
    """Refuse a persona whose arrays are not what its header implies, from the zip directory and
    the .npy member headers only: a crafted member (2 GiB of zeros in a 5 MB file) is refused
    before a byte of it is decompressed; the arrays together must fit in the available memory."""
    from .._memory import available_memory
    from ..io import npz_members

    n, (W, H), r = len(photos), params.size, params.subspace_rank
    if not (0 < W <= 4096 and 0 < H <= 4096 and 0 <= r <= 64):
        raise _bad(path, f"corrupt persona header (canonical size {W}x{H}, rank {r})")
    plain, packed = _member_specs(header, params, n)
    want = {k: (np.dtype(dtype), shape) for k, (dtype, shape) in plain.items()}
    for k, (dtype, shape) in packed.items():
        raw = int(np.prod(shape[1:])) * np.dtype(dtype).itemsize
        # deflate's worst case: + 5 bytes per 16 kB block and 11 per stream
        want[k] = (np.dtype(np.uint8), None, n * (raw + 5 * (raw // 16384 + 1) + 11))
        want[f"{k}_offsets"] = (np.dtype(np.int64), (n + 1,))
        want[f"{k}_unpacked"] = (np.dtype(dtype), shape)  # counted in the memory check only
    members = npz_members(path, BadPersonaError, what="persona file")
    total = sum(int(np.prod(s)) * d.itemsize for k, (d, s, *_) in want.items() if k.endswith("_unpacked"))
    for name, m in members.items():
        if name == "header" or name not in want:
            continue
        dtype, shape, *limit = want[name]
        if limit:  # packed streams: 1-D, at most the worst case of deflate
            if m["dtype"] != dtype or m["shape"] is None or len(m["shape"]) != 1 or m["shape"][0] > limit[0]:
                raise _bad(path, f"packed array {name!r} has {m['dtype']} {m['shape']}, expected {dtype} "
                                 f"(m,) with m <= {limit[0]}")
            shape = m["shape"]
        elif m["dtype"] != dtype or m["shape"] != shape:
            raise _bad(path, f"array {name!r} has {m['dtype']} {m['shape']}, expected {dtype} {shape}")
        nbytes = int(np.prod(shape)) * dtype.itemsize
        if not nbytes <= m["file_size"] <= nbytes + 65536:  # + the .npy header
            raise _bad(path, f"corrupt persona file (member {name!r} declares {m['file_size']} bytes "
                             f"for a {nbytes}-byte array)")
        total += nbytes
    avail = available_memory()
    if avail and total > 0.9 * avail:
        raise _bad(path, f"its arrays need {total / 2**30:.1f} GiB, more than the {avail / 2**30:.1f} GiB "
                         "of memory available")
