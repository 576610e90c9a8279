"""The public Python API: real functions with explicit keyword parameters, numpydoc docstrings,
type hints; images as paths / PIL / arrays; errors that are also the built-in exceptions."""

from __future__ import annotations

import hashlib
import inspect
import json
import pydoc
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import facetex
from facetex._resources import sample_path

PUBLIC = ("transfer", "transfer_with_info", "build_persona", "load_persona", "persona_texture", "texture_params",
          "persona_average", "persona_mesh", "puppeteer", "as_image", "parse_iters")
TRANSFER_KEYWORDS = ("method", "preset", "size", "iters", "texture_net", "mrf_weight", "structure_weight",
                     "content_weight", "style_weight", "tv_weight", "init", "seed", "device", "progress", "callback",
                     "save_every", "max_memory")
FACE, OTHER = sample_path("frl_004_neutral.jpg"), sample_path("frl_005_neutral.jpg")


@pytest.mark.parametrize("name", PUBLIC)
def test_public_functions_are_documented_functions(name):
    fn = getattr(facetex, name)
    assert inspect.isfunction(fn), f"facetex.{name} is {type(fn)}"
    doc = inspect.getdoc(fn)
    sections = ["Parameters", "Returns", "Examples"] + (["Raises"] if name not in ("load_persona",) else [])
    for s in sections:
        assert f"\n{s}\n{'-' * len(s)}\n" in f"\n{doc}\n", f"{name}: no numpydoc {s} section"
    sig = inspect.signature(fn)
    documented = doc.split("Returns\n")[0]
    for p in sig.parameters.values():
        assert p.annotation is not inspect.Parameter.empty, f"{name}({p.name}) has no type hint"
        if p.kind is not p.VAR_KEYWORD:
            assert p.name in documented, f"{name}: parameter {p.name} is not documented"
    assert sig.return_annotation is not inspect.Signature.empty


def test_transfer_is_a_function_with_explicit_keywords():
    sig = inspect.signature(facetex.transfer)
    assert list(sig.parameters)[:2] == ["content", "style"]
    for k in TRANSFER_KEYWORDS:
        assert sig.parameters[k].kind is inspect.Parameter.KEYWORD_ONLY, k
    assert sig.parameters["method"].default == "facetex" and sig.parameters["init"].default == "content"
    text = pydoc.render_doc(facetex.transfer, renderer=pydoc.plaintext)
    assert len(text.splitlines()) < 150 and "torch" not in text.lower().replace("torch device", "")
    assert inspect.signature(facetex.transfer_with_info).parameters.keys() >= set(TRANSFER_KEYWORDS)


def test_the_transfer_subpackage_stays_importable():
    code = ("import facetex, facetex.transfer._pipeline as p, facetex.transfer.losses as L, inspect; "
            "from facetex.transfer import mrf_loss, TransferParams, preset, transfer as t2; "
            "import facetex.transfer.methods as m; "
            "assert inspect.isfunction(facetex.transfer) and t2 is facetex.transfer; "
            "assert p.__name__ == 'facetex.transfer._pipeline' and facetex.transfer.losses is L; "
            "assert callable(mrf_loss) and m.METHODS[0] == 'facetex'; print('ok')")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.stdout.strip() == "ok", r.stderr


def test_py_typed_is_shipped():
    root = Path(facetex.__file__).parent
    assert (root / "py.typed").is_file()
    assert '"py.typed"' in (root.parent / "pyproject.toml").read_text()


def test_images_as_path_pil_or_array():
    a = facetex.as_image(FACE)
    assert a.dtype == np.float32 and a.shape == (400, 400, 3)
    assert np.array_equal(facetex.as_image(Image.open(FACE)), a)
    assert np.array_equal(facetex.as_image((a * 255).round().astype(np.uint8)), a)
    assert facetex.as_image(a[..., 0]).shape == (400, 400, 3)  # gray
    rgba = np.dstack([a, np.zeros_like(a[..., :1])])
    assert np.allclose(facetex.as_image(rgba), 1.0)  # transparent: composited on white


@pytest.mark.parametrize("bad, match", [
    (lambda a: a * 255, "divide by 255"),
    (lambda a: np.where(a > 0.5, np.nan, a), "NaN"),
    (lambda a: a[..., :2], "shape"),
    (lambda a: a.astype(np.int64), "dtype"),
    (lambda a: a - 0.5, "negative"),
])
def test_bad_arrays_are_refused_with_a_clear_message(bad, match):
    a = facetex.as_image(FACE)
    with pytest.raises(facetex.BadImageError, match=match) as e:
        facetex.transfer(bad(a), OTHER, iters=1)
    assert isinstance(e.value, ValueError) and "\n" not in str(e.value)


def test_iters_strings_parse_or_fail_clearly():
    assert facetex.parse_iters("2,2,2") == (2, 2, 2)
    assert facetex.parse_iters(5) == (5,) and facetex.parse_iters([3, 4]) == (3, 4)
    assert facetex.parse_iters("0,1", minimum=0) == (0, 1)
    for bad in ("2,x,2", "0,1", "1.5", [1, "a"], True):
        with pytest.raises(ValueError, match="iter"):
            facetex.parse_iters(bad)
    with pytest.raises(facetex.BadInputError, match="comma-separated integers"):
        facetex.transfer(FACE, OTHER, iters="2,x")


def test_bad_options_fail_before_reading_images(tmp_path):
    missing = tmp_path / "missing.jpg"
    with pytest.raises(ValueError, match="unknown method"):
        facetex.transfer(missing, OTHER, method="cyclegan")
    with pytest.raises(ValueError, match="mrf_weight"):
        facetex.transfer(missing, OTHER, mrf_weight=-1)
    with pytest.raises(ValueError, match="unknown transfer option"):
        facetex.transfer(missing, OTHER, no_such_option=1)
    with pytest.raises(ValueError, match="init must be"):
        facetex.transfer(FACE, OTHER, init="noise")
    with pytest.raises(facetex.BadImageError, match="init image is 50x50 px, the content .*: it must have"):
        facetex.transfer(FACE, OTHER, init=np.zeros((50, 50, 3), np.float32))  # before any work


def test_texture_options_are_checked_before_the_persona_is_read(tmp_path):
    tp = facetex.texture_params()
    assert tp.weights == "regional" and tp.neighbours == 3
    assert facetex.texture_params(weights="global", sigma=8).sigma == 8.0
    assert facetex.texture_params(neighbours=5).neighbours == 5
    missing = tmp_path / "missing.persona"
    for kw, match in (({"sigma": 8}, "sigma applies to the paper's global"),
                      ({"weights": "global", "neighbours": 2}, "neighbours applies to the regional"),
                      ({"weights": "global", "sigma": -1}, "positive number"),
                      ({"neighbours": 0}, "positive integer"), ({"weights": "local"}, "weights must be one of")):
        with pytest.raises(ValueError, match=match) as e:
            facetex.persona_texture(missing, fiducials=np.zeros((49, 2)), **kw)
        assert "\n" not in str(e.value)
    with pytest.raises(FileNotFoundError):
        facetex.persona_texture(missing, fiducials=np.zeros((49, 2)), weights="global", sigma=6)


def test_exceptions_are_the_builtin_ones(tmp_path):
    with pytest.raises(FileNotFoundError) as e:
        facetex.read_image(tmp_path / "missing.jpg")
    assert isinstance(e.value, facetex.BadImageError) and e.value.path == str(tmp_path / "missing.jpg")
    with pytest.raises(FileNotFoundError):
        facetex.load_persona(tmp_path / "missing.persona")
    with pytest.raises(OSError) as e:
        facetex.write_image(tmp_path / "nofolder" / "x.png", np.zeros((4, 4, 3)))
    assert isinstance(e.value, facetex.OutputError)
    assert issubclass(facetex.NoFaceError, ValueError) and issubclass(facetex.BadInputError, ValueError)
    assert issubclass(facetex.ModelNotFoundError, FileNotFoundError)
    assert all(issubclass(c, facetex.FacetexError) for c in (facetex.NoFaceError, facetex.OutputError))


def test_python_dash_m_and_version_flags():
    for args in (["-m", "facetex", "-V"], ["-m", "facetex", "--version"]):
        r = subprocess.run([sys.executable, *args], capture_output=True, text=True)
        assert r.returncode == 0 and r.stdout.strip() == f"facetex {facetex.__version__}", r.stderr


def test_transfer_step_image_pastes_the_change_at_full_size():
    content = np.full((100, 120, 3), 0.5, np.float32)
    step = np.full((20, 30, 3), 0.7, np.float32)  # the working region at a coarse level, +0.2 everywhere
    out = facetex.transfer_step_image(content, step, (30, 20, 90, 60), feather=False)
    assert out.shape == content.shape
    assert np.allclose(out[20:60, 30:90], 0.7, atol=1e-5) and np.allclose(out[:20], 0.5) and np.allclose(out[:, :30], 0.5)
    feathered = facetex.transfer_step_image(content, step, (30, 20, 90, 60))
    assert np.allclose(feathered[40, 60], 0.7, atol=1e-5) and 0.5 < feathered[20, 60, 0] < 0.6


def test_transfer_from_paths_and_pil_with_a_progress_bar(capsys):
    calls = []
    out, info = facetex.transfer_with_info(FACE, Image.open(OTHER), size=64, iters="2,2", seed=0, progress=True,
                                           callback=lambda **kw: calls.append(kw["level"]), save_every=1)
    err = capsys.readouterr().err
    assert "facetex" in err and "eval" in err and "100%" in err  # a tqdm bar that stays at the end
    assert out.shape == (400, 400, 3) and out.dtype == np.float32 and 0 <= out.min() and out.max() <= 1
    assert info["seed"] == 0 and info["params"]["iters"] == [2, 2] and calls and set(calls) <= {0, 1}
    again = facetex.transfer(str(FACE), OTHER, size=64, iters=(2, 2), seed=0)
    assert np.array_equal(out, again)  # the same seed, bit for bit


def test_cli_sidecar_holds_the_provenance(tmp_path, capsys):
    from facetex.cli import main

    out = tmp_path / "out.png"
    assert main(["transfer", str(FACE), str(OTHER), "-o", str(out), "--size", "64", "--iters", "2,2", "--seed", "3",
                 "--mrf-weight", "1.5", "--init", "random", "--save-every", "2", "-q"]) == 0
    assert capsys.readouterr().out == ""  # -q: no message
    side = json.loads((tmp_path / "out.png.json").read_text())
    assert side["schema"] == "facetex.provenance/1" and side["command"] == "transfer" and side["seed"] == 3
    assert "--mrf-weight 1.5" in side["command_line"] and side["created_utc"].endswith("+00:00")
    for name, path in (("content", FACE), ("style", OTHER)):
        assert side["inputs"][name]["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    assert side["params"]["command_line_options"]["mrf_weight"] == 1.5 and side["params"]["init"] == "random"
    assert side["params"]["mrf_weight"] == 1.5 and side["params"]["iters"] == [2, 2]
    for lib in ("facetex", "torch", "numpy", "opencv", "dlib", "scipy", "scikit-image", "pyav"):
        assert side["versions"][lib], lib
    assert '"images"' not in (tmp_path / "out.png.json").read_text()
    steps = sorted(tmp_path.glob("out_level*_eval*.png"))
    assert steps and [Path(s).name for s in side["steps"]] == [s.name for s in sorted(steps, key=lambda p: side["steps"].index(str(p)))]
    assert all(Image.open(s).size == (400, 400) for s in steps)  # full size, not the working region
    # a second run refuses to replace the image, its sidecar or the steps
    assert main(["transfer", str(FACE), str(OTHER), "-o", str(out), "--size", "64", "--iters", "2,2"]) == 2


def test_landmarks_json_and_overlay_sidecar(tmp_path, capsys):
    from facetex.cli import main

    noface = tmp_path / "noface.png"
    Image.fromarray(np.full((120, 120, 3), 128, np.uint8)).save(noface)
    assert main(["landmarks", str(noface), "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == {"image": str(noface), "faces": []}
    assert main(["landmarks", str(noface)]) == 2
    assert "no face found" in capsys.readouterr().err
    ov = tmp_path / "ov.png"
    assert main(["landmarks", str(FACE), "-o", str(ov)]) == 0
    assert capsys.readouterr().out.splitlines()[-2:] == [f"wrote {ov}", f"wrote {ov}.json"]
    side = json.loads((tmp_path / "ov.png.json").read_text())
    assert side["command"] == "landmarks" and len(side["faces"][0]["points68"]) == 68


def test_landmarks_json_into_head_ends_quietly(tmp_path):
    cmd = f'"{sys.executable}" -m facetex landmarks "{FACE}" --json | head -2'
    r = subprocess.run(["bash", "-c", cmd], capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.startswith("{") and r.stderr == "", r.stderr


def test_cli_lets_openmp_threads_sleep_unless_told_otherwise():
    code = "import os, facetex.cli as c; c._passive_openmp(); print(os.environ['OMP_WAIT_POLICY'])"
    env = {k: v for k, v in __import__("os").environ.items() if k != "OMP_WAIT_POLICY"}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert r.stdout.strip() == "PASSIVE", r.stderr
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env={**env, "OMP_WAIT_POLICY": "ACTIVE"})
    assert r.stdout.strip() == "ACTIVE", r.stderr
