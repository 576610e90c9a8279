"""Crafted ``.persona`` files (issue 23, third wave): encrypted members, wrongly typed header
fields, absurd arrays, texture stacks stored for other photos."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest

from _robust import assert_one_error, run_cli, sha1s, snapshot
from conftest import has_command

pytestmark = pytest.mark.skipif(not has_command("persona", "average"), reason="`facetex persona` not registered")


def rewrite(src, dst, *, header=None, arrays=None, encrypt=None):
    """A copy of the persona ``src`` with ``header(dict)`` applied to its JSON header, ``arrays[name](a)``
    replacing members, and the zip's "encrypted" flag set on member ``encrypt``."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for info in zin.infolist():
            name, data = info.filename[:-4], zin.read(info)
            if name == "header" and header is not None:
                h = json.loads(np.lib.format.read_array(io.BytesIO(data)).tobytes())
                header(h)
                data = _npy(np.frombuffer(json.dumps(h).encode(), np.uint8))
            if arrays and name in arrays:
                data = _npy(arrays[name](np.lib.format.read_array(io.BytesIO(data))))
            out = zipfile.ZipInfo(info.filename, date_time=(1980, 1, 1, 0, 0, 0))
            out.compress_type = info.compress_type
            zout.writestr(out, data)
    if encrypt:  # the flag bit in the local and the central header (a password-protected member)
        raw = bytearray(dst.read_bytes())
        with zipfile.ZipFile(dst) as z:
            info = z.getinfo(f"{encrypt}.npy")
        raw[info.header_offset + 6] |= 1
        name, k = info.filename.encode(), raw.find(b"PK\x01\x02")
        while k >= 0:
            n = int.from_bytes(raw[k + 28:k + 30], "little")
            if raw[k + 46:k + 46 + n] == name:
                raw[k + 8] |= 1
            k = raw.find(b"PK\x01\x02", k + 4)
        dst.write_bytes(bytes(raw))
    return dst


def _npy(a) -> bytes:
    b = io.BytesIO()
    np.lib.format.write_array(b, np.ascontiguousarray(a), allow_pickle=False)
    return b.getvalue()


def _param(key, value):
    return lambda h: h["parameters"].__setitem__(key, value)


CASES = {
    "encrypted-fiducials": ({"encrypt": "fiducials"}, r"corrupt persona file.*'fiducials.npy' is encrypted"),
    "encrypted-images": ({"encrypt": "images"}, r"'images.npy' is encrypted"),
    "encrypted-header": ({"encrypt": "header"}, r"'header.npy' is encrypted"),
    "tps-smoothing-text": ({"header": _param("tps_smoothing", "abc")},
                           r"parameters.tps_smoothing must be a number, not a string"),
    "flow-alpha-negative": ({"header": _param("flow_alpha", -1)}, r"parameters.flow_alpha"),
    "flow-method-unknown": ({"header": _param("flow_method", "magic")}, r"parameters.flow_method"),
    "size-floats": ({"header": _param("size", [192.5, 240])}, r"parameters.size\[0\] must be an integer"),
    "unknown-parameter": ({"header": _param("colour", 1)}, r"parameters.*colour"),
    "version-true": ({"header": lambda h: h.__setitem__("version", True)},
                     r"version must be an integer, not true"),
    "version-text": ({"header": lambda h: h.__setitem__("version", "4")}, r"version must be an integer, not \"4\""),
    "photo-file-number": ({"header": lambda h: h["photos"][0].__setitem__("file", 7)},
                          r"photos\[0\].file must be a string"),
    "depth-photos-negative": ({"header": lambda h: h.__setitem__("depth_photos", -3)}, r"depth_photos"),
    "fiducials-huge": ({"arrays": {"fiducials": lambda a: a * 1e12}}, r"array 'fiducials' holds .*e\+1\d, outside"),
    "points68-huge": ({"arrays": {"points68": lambda a: a - 1e6}}, r"array 'points68' holds -1e\+06, outside"),
    "poses-1e300": ({"arrays": {"poses": lambda a: np.full_like(a, 1e300)}}, r"array 'poses' holds 1e\+300"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_crafted_persona(capsys, tmp_path, outdir, persona_file, case):
    how, cause = CASES[case]
    path = rewrite(persona_file, tmp_path / f"{case}.persona", **how)
    before = sha1s(path)
    run = run_cli(capsys, "persona", "average", path, "-o", outdir / "a.png")
    assert_one_error(run, names=[path], cause=cause)
    assert sha1s(path) == before and snapshot(outdir) == {}


@pytest.mark.parametrize("case", ["encrypted-fiducials", "tps-smoothing-text", "version-true", "poses-1e300"])
def test_crafted_persona_api(tmp_path, persona_file, case):
    from facetex.errors import BadPersonaError
    from facetex.persona import load_persona

    how, cause = CASES[case]
    path = rewrite(persona_file, tmp_path / "p.persona", **how)
    with pytest.raises(BadPersonaError, match=cause) as e:
        load_persona(path)
    assert "p.persona" in str(e.value) and "\n" not in str(e.value)


def test_rewritten_persona_unchanged_loads(capsys, tmp_path, outdir, persona_file):
    """The rewrite itself keeps a persona valid (the cases above fail for their change only)."""
    path = rewrite(persona_file, tmp_path / "same.persona", header=lambda h: None)
    run = run_cli(capsys, "persona", "average", path, "-o", outdir / "a.png")
    assert run.code == 0, run.err


# ---------------------------------------------------------------- stacks bound to their photos
def _replace_photos(src, dst):
    """``src`` with other photos (its own, colours inverted) in images.npy, its stacks kept."""
    from facetex.persona import load_persona
    from facetex.persona._packed import Packed

    packed = Packed.pack(255 - load_persona(src).images)
    return rewrite(src, dst, arrays={"images": lambda a: packed.blob, "images_offsets": lambda a: packed.offsets})


def test_replaced_photos_recompute_the_stacks(capsys, tmp_path, outdir, persona_file):
    from facetex.persona import load_persona

    path = _replace_photos(persona_file, tmp_path / "swapped.persona")
    before = sha1s(path)
    with pytest.warns(UserWarning, match=r"swapped.persona: its texture stacks were made from other photos "
                                         r"\(images.npy changed\): recomputed"):
        p = load_persona(path)
    assert p.texture_stacks is None
    fresh = tmp_path / "fresh.persona"  # the same photos, stacks computed from them
    p.save(fresh, texture_stacks=False)
    run = run_cli(capsys, "persona", "average", path, "-o", outdir / "swapped.png")
    assert run.code == 0, run.err
    assert "texture stacks were made from other photos" in run.err
    assert run_cli(capsys, "persona", "average", fresh, "-o", outdir / "fresh.png").code == 0
    assert run_cli(capsys, "persona", "average", persona_file, "-o", outdir / "old.png").code == 0
    h = sha1s(*(outdir / f"{n}.png" for n in ("swapped", "fresh", "old")))
    assert h[str(outdir / "swapped.png")] == h[str(outdir / "fresh.png")] != h[str(outdir / "old.png")]
    assert sha1s(path) == before


def test_saved_again_stores_stacks_of_the_new_photos(tmp_path, persona_file):
    import warnings

    from facetex.persona import load_persona

    path = _replace_photos(persona_file, tmp_path / "swapped.persona")
    with pytest.warns(UserWarning):
        load_persona(path).save(tmp_path / "again.persona")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = load_persona(tmp_path / "again.persona")
    assert again.texture_stacks is not None and "sources_crc32" in again.texture_stacks["meta"]


def test_stacks_of_the_same_photos_are_used(persona_file):
    import warnings

    from facetex.persona import load_persona

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        p = load_persona(persona_file)
    assert p.texture_stacks is not None and set(p.texture_stacks["meta"]["sources_crc32"]) >= {"images.npy",
                                                                                               "fiducials.npy"}


def test_bad_sources_crc32_is_one_line(capsys, tmp_path, outdir, persona_file):
    path = rewrite(persona_file, tmp_path / "crc.persona",
                   header=lambda h: h["texture_stacks"].__setitem__("sources_crc32", ["x"]))
    run = run_cli(capsys, "persona", "average", path, "-o", outdir / "a.png")
    assert_one_error(run, names=[path], cause=r"corrupt persona header.*sources_crc32")
