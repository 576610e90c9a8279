"""Is a photo collection one person? Face-descriptor clustering for :func:`build_persona`.

A persona is built from photos of *one* person; a folder that mixes people (50 photos of
one, 50 of another) would otherwise build a chimera without a word. Every usable photo
gets dlib's 128-D face descriptor (:func:`facetex.nets.dlib_resnet.face_descriptor`, the
largest face's); the descriptors are clustered by average linkage (scipy) cut at dlib's
same-person distance 0.6: two groups whose photos are on average further apart than
0.6 are different people. Then:

* the largest identity holds at least ``MAIN_IDENTITY_SHARE`` (80 %) of the usable
  photos: the others are left out (listed as skipped, "another person");
* it holds less: :class:`MixedCollectionError` names how many photos belong to other
  people, unless a mixed collection is allowed (``allow_mixed``), which keeps every photo.
"""

from __future__ import annotations

import numpy as np

from ..errors import BadInputError

__all__ = ["MAIN_IDENTITY_SHARE", "MixedCollectionError", "photo_descriptor", "cluster_identities",
           "select_main_identity"]

#: the largest identity must hold at least this share of the usable photos
MAIN_IDENTITY_SHARE = 0.8


class MixedCollectionError(BadInputError):
    """The photo collection holds several people and none has ``MAIN_IDENTITY_SHARE`` of the photos.
    ``main``: photos of the largest identity; ``others``: photos of the other people; ``people``:
    identities found."""

    def __init__(self, message: str, path=None, *, main: int = 0, others: int = 0, people: int = 0):
        super().__init__(message, path=path)
        self.main, self.others, self.people = main, others, people


def photo_descriptor(image: np.ndarray, points68: np.ndarray) -> np.ndarray:
    """dlib's 128-D descriptor (float32) of the face with ``points68`` in ``image`` (float RGB)."""
    from ..nets.dlib_resnet import face_descriptor

    return face_descriptor(image, points68).astype(np.float32)


def cluster_identities(descriptors, threshold: float | None = None) -> np.ndarray:
    """Identity label of every descriptor (n, 128): 0 for the largest group, 1 for the next…
    Average-linkage clusters cut at ``threshold`` (default dlib's 0.6); ties in size go to the
    group of the earliest photo."""
    from ..nets.dlib_resnet import SAME_PERSON_THRESHOLD

    d = np.asarray(descriptors, np.float64)
    n = len(d)
    if n == 0:
        return np.zeros(0, int)
    if n == 1:
        return np.zeros(1, int)
    from scipy.cluster.hierarchy import fcluster, linkage

    t = SAME_PERSON_THRESHOLD if threshold is None else float(threshold)
    raw = fcluster(linkage(d, method="average", metric="euclidean"), t=t, criterion="distance")
    groups = sorted(set(raw.tolist()), key=lambda g: (-int((raw == g).sum()), int(np.argmax(raw == g))))
    remap = {g: k for k, g in enumerate(groups)}
    return np.array([remap[g] for g in raw.tolist()], int)


def select_main_identity(results: list[dict], *, allow_mixed: bool = False, share: float = MAIN_IDENTITY_SHARE,
                         threshold: float | None = None, path=None) -> tuple[list[dict], list[dict]]:
    """Split usable photos (dicts with a ``"descriptor"``) into (kept, left out as
    {"file", "reason"}) as described in the module docstring. ``path`` (the folder) is
    named by :class:`MixedCollectionError`. Photos without a descriptor are kept."""
    with_d = [r for r in results if r.get("descriptor") is not None]
    if allow_mixed or len(with_d) < 2:
        return list(results), []
    labels = cluster_identities(np.stack([r["descriptor"] for r in with_d]), threshold)
    n = len(labels)
    main = int((labels == 0).sum())
    people = int(labels.max()) + 1
    if people == 1:
        return list(results), []
    others = n - main
    if main < share * n:
        raise MixedCollectionError(
            f"photos of more than one person: the largest identity holds {main} of the {n} usable photos "
            f"({100 * main / n:.0f} %, at least {100 * share:.0f} % needed); {others} photos belong to "
            f"{people - 1} other {'person' if people == 2 else 'people'} (face-descriptor distance > "
            f"{0.6 if threshold is None else threshold}): remove them", path=path,
            main=main, others=others, people=people)
    other = {id(r) for r, lab in zip(with_d, labels) if lab != 0}
    kept = [r for r in results if id(r) not in other]
    dropped = [{"file": r["file"], "reason": "another person (not the collection's main identity)"}
               for r in results if id(r) in other]
    return kept, dropped
