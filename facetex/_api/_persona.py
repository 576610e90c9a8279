"""The public persona API: :func:`build_persona`, :func:`load_persona`, :func:`persona_texture`,
:func:`texture_params`, :func:`persona_average`, :func:`persona_mesh` and :class:`Mesh`."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Sequence, Union

import numpy as np

from ..errors import BadInputError

if TYPE_CHECKING:  # pragma: no cover

    from ..persona.collection import Persona
    from ..persona.params import TextureParams


from ..io import ImageLike, as_image
from ._inputs import Progress, _progress

__all__ = [
    "build_persona",
    "load_persona",
    "persona_texture",
    "texture_params",
    "persona_average",
    "persona_mesh",
    "Mesh",
    "PersonaLike",
]


# --------------------------------------------------------------------------- persona
PersonaLike = Union[str, os.PathLike, "Persona"]


def _persona(persona: PersonaLike) -> "Persona":
    if isinstance(persona, (str, os.PathLike)):
        return load_persona(persona)
    if hasattr(persona, "images") and hasattr(persona, "fiducials"):
        return persona
    raise BadInputError(f"persona must be a .persona path or a Persona, not {type(persona).__name__}")


def build_persona(photo_dir: str | os.PathLike, *, jobs: int = 2, min_photos: int = 10,
                  allow_mixed: bool = False, files: Sequence[str | os.PathLike] | None = None,
                  progress: Progress = False) -> "Persona":
    """Build a persona from a folder of photos of one person (Suwajanakorn et al. 2015, §4-5).

    Every photo is detected, frontalized and pose-corrected; the usable ones are aligned to
    their mean (TPS + collection flow) and the average 3D face is reconstructed.

    Parameters
    ----------
    photo_dir : str or os.PathLike
        Folder of JPEG/PNG photos of one person (>= ``min_photos`` usable).
    jobs : int
        Worker processes.
    min_photos : int
        Fewest usable photos accepted.
    allow_mixed : bool
        Keep all photos even when they show several people (default: photos of other people
        are left out when one person has >= 80 % of them, otherwise the build is refused).
    files : sequence of paths, optional
        Use only these files of the folder (e.g. a leave-out evaluation).
    progress : bool or callable
        True shows a tqdm bar.

    Returns
    -------
    facetex.persona.Persona
        Save it with ``persona.save("NAME.persona")``.

    Raises
    ------
    FileNotFoundError
        The folder does not exist.
    ValueError
        (:class:`facetex.BadInputError`) too few usable photos, or photos of several people.

    Examples
    --------
    >>> import facetex
    >>> p = facetex.build_persona("photos/george", jobs=2, progress=True)  # doctest: +SKIP
    >>> p.save("george.persona")  # doctest: +SKIP
    """
    from ..io import check_input_dir
    from ..persona import PersonaParams
    from ..persona import build_persona as _build
    from ..persona.build import _list_photos

    folder = check_input_dir(photo_dir, BadInputError, what="photo folder")
    n = len(files) if files is not None else len(_list_photos(folder))
    from ..persona.build import SHAPE_STEPS

    # two passes over the photos, then the average shape's steps (each stage named on the bar)
    with _progress(progress, 2 * n + SHAPE_STEPS, "persona", "step") as bar:
        return _build(folder, jobs=int(jobs), progress=bar, params=PersonaParams(min_photos=int(min_photos)),
                      files=files, allow_mixed=allow_mixed)


def load_persona(path: str | os.PathLike) -> "Persona":
    """Read a ``.persona`` file written by :func:`build_persona` / ``facetex persona build``.

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    facetex.persona.Persona
        The person's photos, landmarks, flows, shape and texture stacks.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ValueError
        (:class:`facetex.BadPersonaError`) corrupt, another format or a newer version.

    Examples
    --------
    >>> import facetex
    >>> p = facetex.load_persona("george.persona")  # doctest: +SKIP
    >>> len(p)  # usable photos  # doctest: +SKIP
    519
    """
    from ..errors import BadPersonaError, PersonaNotFoundError
    from ..io import as_path
    from ..persona import load_persona as _load

    path = as_path(path, BadPersonaError, "persona file")
    if not os.path.lexists(path):
        raise PersonaNotFoundError("persona file not found: build one with `facetex persona build`", path=path)
    return _load(path)


def persona_texture(persona: PersonaLike, *, like: ImageLike | None = None,
                    fiducials: np.ndarray | Sequence[Sequence[float]] | None = None,
                    method: Literal["ours", "static", "weighted", "prewarp"] = "ours",
                    weights: Literal["regional", "global"] = "regional", sigma: float | None = None,
                    neighbours: int | None = None, progress: Progress = False) -> np.ndarray:
    """The persona's face texture for a target expression (Suwajanakorn et al. 2015, Eq. 3).

    Parameters
    ----------
    persona : str, os.PathLike or Persona
        A ``.persona`` file or a loaded persona.
    like : image, optional
        A reference photo (path, PIL or array) whose expression is wanted.
    fiducials : array_like, optional
        Or the target's 49 (or 68) (x, y) fiducials in the persona's canonical frame.
    method : {"ours", "static", "weighted", "prewarp"}
        The paper's expression-weighted multi-scale blend ("ours") or a Fig. 5 baseline.
    weights : {"regional", "global"}
        Expression weights: regional (mouth, eyes and the rest of the face each weighted by
        their own normalised fiducials, blended spatially) or global (the paper's Eq. 2/3:
        all fiducials, one ``sigma``, Laplacian exponent alpha 1).
    sigma : float, optional
        ``weights="global"`` only: expression-similarity sigma of Eq. 2/3 (default 10,
        typically 6-12).
    neighbours : int, optional
        ``weights="regional"`` only: each region's sigma is the target's distance to its
        K-th nearest photo / 2 (default 3).
    progress : bool or callable
        True shows a tqdm bar.

    Returns
    -------
    numpy.ndarray
        The texture, float32 (H, W, 3) in [0, 1] in the canonical frame.

    Raises
    ------
    ValueError
        Neither or both of ``like`` and ``fiducials``; bad fiducials; no face in ``like``;
        ``sigma`` with regional weights or ``neighbours`` with global ones.

    Examples
    --------
    >>> import facetex
    >>> tex = facetex.persona_texture("george.persona", like="smiling.jpg")  # doctest: +SKIP
    >>> paper = facetex.persona_texture("george.persona", like="smiling.jpg",
    ...                                 weights="global", sigma=10)  # doctest: +SKIP
    """
    from ..persona import synthesize_texture

    if (like is None) == (fiducials is None):
        raise BadInputError("give exactly one of like= (a reference photo) and fiducials=")
    tp = texture_params(weights=weights, sigma=sigma, neighbours=neighbours)
    p = _persona(persona)
    kw: dict[str, Any] = {}
    if like is not None:
        kw["reference"] = like if isinstance(like, (str, os.PathLike)) else as_image(like, "reference image")
    else:
        kw["fiducials"] = np.asarray(fiducials, np.float64)
    with _progress(progress, None, "texture", "step") as bar:
        return synthesize_texture(p, method=method, params=tp, progress=bar, **kw)


def texture_params(*, weights: Literal["regional", "global"] = "regional", sigma: float | None = None,
                   neighbours: int | None = None) -> "TextureParams":
    """Persona texture parameters from the user-facing options, checked.

    Parameters
    ----------
    weights : {"regional", "global"}
        Regional expression weights (ours) or the paper's global Eq. 2/3 weights.
    sigma : float, optional
        Global weights only: sigma of Eq. 2/3 (default 10).
    neighbours : int, optional
        Regional weights only: K of the adaptive per-region sigma (default 3).

    Returns
    -------
    facetex.persona.TextureParams
        The options, validated, for :func:`persona_texture` and :func:`facetex.puppeteer`.

    Raises
    ------
    ValueError
        (:class:`facetex.BadInputError`) an unknown ``weights``, a non-positive ``sigma`` or
        ``neighbours``, or an option that does not apply to ``weights``.

    Examples
    --------
    >>> import facetex
    >>> facetex.texture_params(weights="global", sigma=8).sigma
    8.0
    """
    import math

    from ..persona import WEIGHTS, TextureParams

    if weights not in WEIGHTS:
        raise BadInputError(f"weights must be one of {', '.join(map(repr, WEIGHTS))}, not {weights!r}")
    kw: dict[str, Any] = {"weights": weights}
    if sigma is not None:
        if weights != "global":
            raise BadInputError("sigma applies to the paper's global weights (weights='global'); the regional "
                                "weights measure their own sigma: set neighbours instead")
        try:
            s = float(sigma)
        except (TypeError, ValueError):
            s = math.nan
        if not (math.isfinite(s) and s > 0):
            raise BadInputError(f"sigma must be a positive number (typically 6-12), not {sigma!r}")
        kw["sigma"] = s
    if neighbours is not None:
        if weights != "regional":
            raise BadInputError("neighbours applies to the regional weights (weights='regional'); the global "
                                "weights take sigma")
        if not isinstance(neighbours, (int, np.integer)) or isinstance(neighbours, bool) or neighbours < 1:
            raise BadInputError(f"neighbours must be a positive integer, not {neighbours!r}")
        kw["neighbours"] = int(neighbours)
    return TextureParams(**kw)


def persona_average(persona: PersonaLike, *, stage: Literal["a", "b", "c", "d"] = "d") -> np.ndarray:
    """The persona's average face (Suwajanakorn et al. 2015, Fig. 6 stages a-d).

    Parameters
    ----------
    persona : str, os.PathLike or Persona
        A ``.persona`` file or a loaded persona.
    stage : {"a", "b", "c", "d"}
        a: frontalized, b: + TPS, c: + dense warp, d: + multi-scale blend.

    Returns
    -------
    numpy.ndarray
        The texture, float32 (H, W, 3) in [0, 1] in the canonical frame.

    Raises
    ------
    ValueError
        Unknown stage or a bad persona file.

    Examples
    --------
    >>> import facetex
    >>> avg = facetex.persona_average("george.persona", stage="d")  # doctest: +SKIP
    """
    from ..persona import average_face

    if stage not in ("a", "b", "c", "d"):
        raise BadInputError(f"stage must be 'a', 'b', 'c' or 'd', not {stage!r}")
    return average_face(_persona(persona), stage)


@dataclass
class Mesh:
    """A textured triangle mesh and where its depth came from.

    Parameters
    ----------
    vertices : numpy.ndarray
        (n, 3) in canonical px (OBJ axes: x right, y up, z towards the viewer).
    faces : numpy.ndarray
        (m, 3) vertex indices.
    uv : numpy.ndarray
        (n, 2) texture coordinates in [0, 1].
    texture : numpy.ndarray
        (H, W, 3) float32.
    depth_source : {"collection", "generic"}
        The person's photometric-stereo shape or the generic one.
    depth_origin : {"stored", "computed"} or None
        "stored" (validated at build time), "computed" (an older persona, reconstructed and
        validated now) or None (generic on request).
    depth_photos : int
        Photos the shape was reconstructed from.
    shape_reason : str
        Why that shape was used.
    shape_validation : dict or None
        The photometric validation's numbers and verdict (None with ``shape="generic"``).
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    texture: np.ndarray
    depth_source: str
    depth_origin: str | None
    depth_photos: int
    shape_reason: str = ""
    shape_validation: dict | None = None

    def save(self, path: str | os.PathLike, *, overwrite: bool = False, inputs=(),
             extra_files: dict | None = None) -> Path:
        """Write ``path`` (.obj) with its ``.mtl`` and ``.png`` texture beside it (and
        ``extra_files``, {path: bytes}), all or none."""
        from ..errors import OutputError
        from ..puppet.mesh_io import write_obj

        path = Path(path)
        if path.suffix.lower() != ".obj":
            raise OutputError("mesh file name must end in .obj", path=path)
        write_obj(path, self.vertices, self.faces, self.uv, self.texture, overwrite=overwrite, inputs=inputs,
                  extra_files=extra_files)
        return path


def persona_mesh(persona: PersonaLike, *, step: int = 1,
                 shape: Literal["collection", "generic"] = "collection") -> Mesh:
    """The persona's average 3D face as a textured mesh (Suwajanakorn et al. 2015, §4).

    Parameters
    ----------
    persona : str, os.PathLike or Persona
        A ``.persona`` file or a loaded persona.
    step : int
        Grid step in canonical px (1 = every pixel; at most 1/8 of the frame width).
    shape : {"collection", "generic"}
        The persona's photometric-stereo average depth when it passed its photometric
        validation on held-out photos (else the generic face, and ``mesh.shape_reason``
        says why) or the generic face.

    Returns
    -------
    Mesh
        ``mesh.save("face.obj")`` writes the .obj, .mtl and .png texture;
        ``mesh.depth_source``, ``mesh.shape_reason`` and ``mesh.shape_validation`` say
        which shape was used and why.

    Raises
    ------
    ValueError
        A step that leaves too few grid points, an unknown shape.

    Examples
    --------
    >>> import facetex
    >>> facetex.persona_mesh("george.persona", step=2).save("face.obj")  # doctest: +SKIP
    """
    from ..persona import average_face
    from ..persona.align import face_region
    from ..persona.build import average_shape
    from ..puppet.mesh_io import depth_to_mesh
    from ..puppet.shape import checked_depth, generic_depth_px

    if shape not in ("collection", "generic"):
        raise BadInputError(f"shape must be 'collection' or 'generic', not {shape!r}")
    p = _persona(persona)
    W, H = p.size if hasattr(p, "size") else p.params.size
    max_step = max(1, min(W, H) // 8)
    if not isinstance(step, (int, np.integer)) or not 1 <= step <= max_step:
        raise BadInputError(f"step {step} leaves too few grid points in the {W}x{H} canonical frame: "
                            f"use 1..{max_step}")
    region = face_region(p.points68.mean(axis=0), (H, W))
    origin, n_used, validation = None, 0, None
    if shape == "generic":
        depth, source = generic_depth_px((W, H)).astype("float64"), "generic"
        reason = "generic face on request (shape='generic')"
    else:
        if p.shape_report is not None:  # reconstructed and validated at build time
            raw, n_used, origin, validation = p.depth, p.depth_photos, "stored", p.shape_report
        else:  # a version-1 persona, or one built before the validation: reconstruct and validate now
            raw, n_used, validation = average_shape(p)
            origin = "computed"
        if not validation.get("accepted"):
            raw, n_used = None, 0
        depth, source = checked_depth(raw, region, (W, H))
        if source == "collection":
            reason = validation.get("reason", "")
        elif not validation.get("accepted"):
            reason = f"generic face: {validation.get('reason', 'the shape was rejected')}"
        else:
            reason = ("generic face: the validated depth is implausible (RMS difference to the generic face "
                      "above 8 % of the frame width)")
    vertices, faces, uv = depth_to_mesh(depth, region, step=int(step))
    if len(faces) == 0:
        raise BadInputError(f"step {step} leaves no triangle on the face: use a smaller step")
    return Mesh(vertices, faces, uv, average_face(p, "d"), source, origin, int(n_used), reason, validation)


