"""Issue 13: a collection of two people is not built into one persona without a word.

Photo collections made from the bundled faces: frl_004 (person A) and frl_005 (person B),
jittered and relit; dlib's descriptors put A's photos < 0.3 apart and A-B pairs > 0.7."""

from __future__ import annotations

import numpy as np
import pytest

from _robust import assert_one_error, run_cli, snapshot
from facetex.persona.identity import MAIN_IDENTITY_SHARE, cluster_identities, select_main_identity

OPTS = ["--jobs", "1", "--min-photos", "3"]


def test_half_and_half_is_refused(capsys, two_people, outdir):
    folder = two_people["half"]
    before = snapshot(folder)
    run = run_cli(capsys, "persona", "build", folder, "-o", outdir / "p.persona", *OPTS)
    assert_one_error(run, names=[folder], cause=r"more than one person.*largest identity holds 5 of the 10 usable "
                                                 r"photos.*5 photos belong to 1 other person.*--allow-mixed")
    assert snapshot(outdir) == {}
    assert snapshot(folder) == before


def test_main_identity_kept_when_it_dominates(capsys, two_people, outdir):
    from facetex.persona import load_persona

    folder = two_people["mostly"]
    run = run_cli(capsys, "persona", "build", folder, "-o", outdir / "p.persona", *OPTS)
    assert run.code == 0, run.err
    p = load_persona(outdir / "p.persona")
    assert sorted(p.photos) == [f"a{i}.jpg" for i in range(8)]
    assert [s["file"] for s in p.skipped] == ["b0.jpg"] and "another person" in p.skipped[0]["reason"]
    assert "skipped b0.jpg: another person" in run.err


def test_allow_mixed_builds_from_everyone(capsys, two_people, outdir):
    from facetex.persona import load_persona

    run = run_cli(capsys, "persona", "build", two_people["half"], "-o", outdir / "p.persona", *OPTS, "--allow-mixed")
    assert run.code == 0, run.err
    assert len(load_persona(outdir / "p.persona")) == 10


def test_descriptor_clusters_of_the_bundled_people(two_people):
    """The fixtures are what the tests above assume: two identities, 5 + 5."""
    from facetex.io import read_image
    from facetex.landmarks import detect_face
    from facetex.persona.identity import photo_descriptor

    paths = sorted(two_people["half"].iterdir())
    d = []
    for p in paths:
        img = read_image(p)
        d.append(photo_descriptor(img, detect_face(img).points68))
    labels = cluster_identities(np.stack(d))
    assert sorted(np.bincount(labels).tolist()) == [5, 5]
    assert len({labels[i] for i, p in enumerate(paths) if p.name.startswith("a")}) == 1


def _blobs(sizes, seed=0, spread=0.1, dim=128):
    """Synthetic descriptors: one tight cluster per size, cluster centres ~1.4 apart."""
    rng = np.random.default_rng(seed)
    out = []
    for k, n in enumerate(sizes):
        c = np.zeros(dim)
        c[k] = 1.0
        out += list(c + rng.normal(0, spread / np.sqrt(dim), (n, dim)))
    return np.asarray(out)


@pytest.mark.parametrize("sizes, kept, raises", [
    ((10,), 10, False),            # one person
    ((8, 2), 8, False),            # 80 %: the main identity is kept
    ((7, 3), None, True),          # 70 %: refused
    ((4, 3, 3), None, True),       # three people
    ((9, 1), 9, False),            # one stray photo
])
def test_select_main_identity_rule(sizes, kept, raises):
    from facetex.persona.identity import MixedCollectionError

    desc = _blobs(sizes)
    results = [{"file": f"p{i}.jpg", "descriptor": d} for i, d in enumerate(desc)]
    if raises:
        with pytest.raises(MixedCollectionError) as e:
            select_main_identity(results, path="folder")
        assert e.value.main == sizes[0] and e.value.others == sum(sizes[1:])
        assert f"{sum(sizes[1:])} photos belong to {len(sizes) - 1} other" in str(e.value)
        good, dropped = select_main_identity(results, allow_mixed=True)
        assert len(good) == sum(sizes) and dropped == []
    else:
        good, dropped = select_main_identity(results)
        assert len(good) == kept and len(dropped) == sum(sizes) - kept
        assert all(int(r["file"][1:-4]) < sizes[0] for r in good)
    assert MAIN_IDENTITY_SHARE == 0.8


def test_cluster_labels_largest_first():
    labels = cluster_identities(_blobs((2, 5)))
    assert labels.tolist() == [1, 1, 0, 0, 0, 0, 0]
    assert cluster_identities(np.zeros((0, 128))).tolist() == []
