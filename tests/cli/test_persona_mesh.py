"""``facetex persona mesh``: the persona's average 3D face as .obj + .mtl + texture, end to end
on a small persona built from variants of the bundled frl_004 photos."""

import json

import cv2
import numpy as np
import pytest

from facetex._resources import sample_path
from facetex.cli import main
from facetex.io import read_image, write_image
from facetex.persona import PersonaParams, average_face, build_persona, load_persona
from facetex.persona.align import face_region
from facetex.puppet.mesh_io import read_obj
from facetex.puppet.shape import generic_depth_px

SIZE = (96, 120)


@pytest.fixture(scope="module")
def persona_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("photos")
    for name in ("frl_004_neutral", "frl_004_smiling"):
        img = cv2.resize(read_image(sample_path(f"{name}.jpg")), (240, 240), interpolation=cv2.INTER_AREA)
        for k, (gain, angle) in enumerate([(1.0, 0), (0.8, 0), (1.15, 3), (0.9, -3)]):
            m = cv2.getRotationMatrix2D((120, 120), angle, 1.0)
            write_image(d / f"{name}_{k}.jpg", np.clip(cv2.warpAffine(img, m, (240, 240)) * gain, 0, 1))
    p = build_persona(d, jobs=1, params=PersonaParams(size=SIZE, min_photos=6))
    return p.save(d / "p.persona")


def _run(capsys, *argv):
    code = main(["persona", "mesh", *map(str, argv), "--json"])
    out = capsys.readouterr()
    return code, (json.loads(out.out) if code == 0 else None), out.err


def test_mesh_from_stored_depth(persona_file, tmp_path, capsys):
    persona = load_persona(persona_file)
    W, H = SIZE
    # 8 photos are too few to reconstruct and validate a shape: stored as rejected, with the reason
    assert persona.depth is not None and np.isnan(persona.depth).all() and persona.depth_photos == 0
    assert persona.shape_report["accepted"] is False and "too few photos" in persona.shape_report["reason"]
    region = face_region(persona.points68.mean(axis=0), (H, W))
    want_depth = generic_depth_px(SIZE)

    obj = tmp_path / "face.obj"
    code, rep, _ = _run(capsys, persona_file, "-o", obj)
    assert code == 0
    assert rep["depth_source"] == "generic" and rep["depth_origin"] == "stored" and rep["depth_photos"] == 0
    assert "too few photos" in rep["shape_reason"] and rep["shape_validation"]["accepted"] is False
    assert rep["paths"] == {"obj": str(obj), "mtl": str(tmp_path / "face.mtl"), "texture": str(tmp_path / "face.png"),
                            "sidecar": str(tmp_path / "face.obj.json")}
    side = json.loads((tmp_path / "face.obj.json").read_text())
    assert side["command"] == "persona mesh" and side["inputs"]["persona"]["sha256"]
    assert side["result"]["shape_reason"] == rep["shape_reason"]
    v, f, uv = read_obj(obj)
    assert len(v) == rep["vertices"] == int(region.sum()) and len(f) == rep["faces"] > len(v)
    xs, ys = v[:, 0].astype(int), v[:, 1].astype(int)
    assert region[ys, xs].all() and np.allclose(v[:, 2], want_depth[ys, xs], atol=1e-5)
    assert np.allclose(uv, np.stack([(xs + 0.5) / W, (ys + 0.5) / H], 1), atol=1e-5)
    assert "map_Kd face.png" in (tmp_path / "face.mtl").read_text()
    tex = read_image(tmp_path / "face.png")
    assert tex.shape == (H, W, 3) and np.abs(tex - average_face(persona, "d")).max() < 1 / 255 + 1e-6

    # existing outputs are kept unless --overwrite; --step thins the grid; generic shape on request
    code, _, err = _run(capsys, persona_file, "-o", obj)
    assert code != 0 and "exists" in err and err.count("\n") == 1
    code, rep2, _ = _run(capsys, persona_file, "-o", obj, "--step", 3, "--shape", "generic", "--overwrite")
    assert code == 0 and rep2["depth_source"] == "generic" and rep2["depth_origin"] is None
    v2, _, _ = read_obj(obj)
    assert len(v2) == int(region[::3, ::3].sum())
    assert np.allclose(v2[:, 2], generic_depth_px(SIZE)[v2[:, 1].astype(int), v2[:, 0].astype(int)], atol=1e-5)


def test_mesh_uses_a_validated_stored_depth(persona_file, tmp_path, capsys):
    # a stored depth that passed its validation (a 3 px bump on the template, NaN off the face) is used
    # as it is, and the report quotes the validation
    persona = load_persona(persona_file)
    W, H = SIZE
    region = face_region(persona.points68.mean(axis=0), (H, W))
    yy, xx = np.mgrid[0:H, 0:W]
    bumped = generic_depth_px(SIZE) + 3.0 * np.exp(-((xx - W / 2) ** 2 + (yy - H / 2) ** 2) / 200.0)
    persona.depth = np.where(region, bumped, np.nan).astype(np.float32)
    persona.depth_photos = 8
    persona.shape_report = {"accepted": True, "reason": "the person's shape explains it better (test)",
                            "rms_person": 0.05, "rms_generic": 0.06}
    pf = persona.save(tmp_path / "bumped.persona")
    code, rep, _ = _run(capsys, pf, "-o", tmp_path / "b.obj")
    assert code == 0 and rep["depth_source"] == "collection" and rep["depth_origin"] == "stored"
    assert rep["shape_validation"]["rms_person"] == 0.05 and "(test)" in rep["shape_reason"]
    v, _, _ = read_obj(tmp_path / "b.obj")
    assert np.allclose(v[:, 2], bumped[v[:, 1].astype(int), v[:, 0].astype(int)], atol=1e-4)


def test_mesh_of_version1_persona_computes_depth(persona_file, tmp_path, capsys):
    persona = load_persona(persona_file)
    head = persona.header()
    head["version"] = 1
    del head["depth_photos"]
    v1 = tmp_path / "v1.persona"
    arrays = {k: getattr(persona, k) for k in ("images", "visibility", "fiducials", "points68", "poses", "flows",
                                               "subspace")}
    with open(v1, "wb") as fh:
        np.savez(fh, header=np.frombuffer(json.dumps(head).encode(), np.uint8), **arrays)
    code, rep, _ = _run(capsys, v1, "-o", tmp_path / "v1.obj", "--step", 2)
    assert code == 0 and rep["depth_origin"] == "computed" and rep["depth_photos"] == 0
    assert rep["depth_source"] == "generic" and "too few photos" in rep["shape_reason"]
    region = face_region(persona.points68.mean(axis=0), (SIZE[1], SIZE[0]))
    assert len(read_obj(tmp_path / "v1.obj")[0]) == rep["vertices"] == int(region[::2, ::2].sum())


def test_mesh_errors_name_the_file(persona_file, tmp_path, capsys):
    code, _, err = _run(capsys, persona_file, "-o", tmp_path / "face.ply")
    assert code != 0 and "face.ply" in err and ".obj" in err and err.count("\n") == 1
    (tmp_path / "taken.png").write_bytes(b"x")  # the texture beside the mesh exists: nothing is written
    code, _, err = _run(capsys, persona_file, "-o", tmp_path / "taken.obj")
    assert code != 0 and "taken.png" in err and not (tmp_path / "taken.obj").exists()
    code, _, err = _run(capsys, tmp_path / "nope.persona", "-o", tmp_path / "x.obj")
    assert code != 0 and "nope.persona" in err and err.count("\n") == 1
    code, _, err = _run(capsys, persona_file, "-o", tmp_path / "x.obj", "--step", 0)
    assert code != 0 and "--step" in err
