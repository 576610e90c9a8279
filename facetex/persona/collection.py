"""A persona: a person's photo collection, frontalized and aligned (Tom Hanks Sec. 5).

:func:`~facetex.persona.build.build_persona` reads a folder of photos of one person and, per photo,
detects the face and its landmarks, frontalizes it with the generic 3D face and
keeps the frontal image, its visibility and the pose-corrected 49 fiducials F^i.
Then, once for the collection (the target-independent part of Sec. 5), it aligns
every photo to the collection's mean fiducials M ("neutral frame"):

1. TPS (Eq. 1, lambda = 10) from M to F^i;
2. collection flow: the TPS-warped stack is projected onto its rank-4 appearance
   subspace (the mean plus 4 principal components, i.e. a centred SVD, computed on
   the pixels inside the face mask) and every warped photo is warped by the optical
   flow (alpha = 0.3) from its projection to it.

Synthesis for a target F^T then composes one TPS M -> F^T with these alignments
(see :mod:`facetex.persona.texture`). Last, the average 3D face (Tom Hanks Sec. 4):
robust photometric stereo on (at most ``shape_photos``) aligned photos, accepted only when it
passes a photometric validation on held-out photos, see :func:`~facetex.persona.build.average_shape`.
``.persona`` files are ``.npz`` zips with a JSON header, loaded with ``allow_pickle=False``;
version 2 adds the average depth (version 1 files load with ``depth=None``); version 3 the
texture synthesis's precomputed stacks (float16, ~0.5 MB per photo); version 4 packs the photos,
visibilities and flows losslessly (:mod:`facetex.persona._packed`, unpacked on first use) and
stores, instead of the stacks, every photo aligned to the neutral frame with its confidence, in
8 bits, from which the stacks are rebuilt at load (:func:`facetex.persona.stacks.stored_stacks`):
~0.15 MB per photo instead of ~0.86. Files without stacks compute them when a texture is first
synthesized.

The object and its saving are in :mod:`._persona`, the reading and checking of files in
:mod:`._persona_file`.
"""

from __future__ import annotations

from ._persona import (
    IMAGE_EXTENSIONS,
    PERSONA_FORMAT,
    PERSONA_VERSION,
    SUBSPACE_DTYPE,  # noqa: F401 - public, not in __all__ (as before the split)
    Persona,
    PersonaParams,
)
from ._persona_file import load_persona, read_persona_header

__all__ = [  # in the order of the reference page
    "PERSONA_FORMAT", "PERSONA_VERSION", "IMAGE_EXTENSIONS", "PersonaParams", "Persona",
    "read_persona_header", "load_persona",
]
