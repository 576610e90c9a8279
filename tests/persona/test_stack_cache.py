"""The on-disk cache of a persona's rebuilt texture stacks: written once, memory-mapped after, the
same blends; ignored when it does not match."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def persona_path(tmp_path_factory):
    from _photos import build_tiny_persona

    return build_tiny_persona(tmp_path_factory.mktemp("cache_persona") / "p.persona", seed=1)


def test_written_then_mapped_with_the_same_blends(persona_path, tmp_path):
    from facetex.persona import TextureParams, load_persona
    from facetex.persona._stack_cache import stack_cache_folder
    from facetex.persona.stacks import prepare_persona
    from facetex.persona.texture import blend_textures

    tp = TextureParams()
    folder = stack_cache_folder(tmp_path, persona_path, tp)
    plain = load_persona(persona_path)
    targets = plain.fiducials[:3]
    want = blend_textures(plain, targets, params=tp)
    first = load_persona(persona_path)
    prepare_persona(first, tp, cache=folder)
    assert (folder / "meta.json").is_file()
    np.testing.assert_array_equal(blend_textures(first, targets, params=tp), want)
    second = load_persona(persona_path)
    prep = prepare_persona(second, tp, cache=folder)
    assert all(isinstance(seg.stack, np.memmap) for segs in prep.segments for seg in segs)  # mapped, not rebuilt
    np.testing.assert_array_equal(blend_textures(second, targets, params=tp), want)


def test_a_cache_that_does_not_match_is_ignored(persona_path, tmp_path):
    import json

    from facetex.persona import TextureParams, load_persona
    from facetex.persona._stack_cache import read_stack_cache, stack_cache_folder
    from facetex.persona.stacks import prepare_persona

    tp = TextureParams()
    folder = stack_cache_folder(tmp_path, persona_path, tp)
    prep = prepare_persona(load_persona(persona_path), tp, cache=folder)
    meta = json.loads((folder / "meta.json").read_text())
    meta["n"] += 1
    (folder / "meta.json").write_text(json.dumps(meta))
    assert read_stack_cache(prep, folder) is False
    (folder / "meta.json").write_text("not json")
    assert read_stack_cache(prep, folder) is False
    assert stack_cache_folder(tmp_path, persona_path, TextureParams(neighbours=5)) != folder or \
        TextureParams(neighbours=5).stack_key() == tp.stack_key()


def test_a_rewritten_persona_replaces_its_old_cache(persona_path, tmp_path):
    import os
    import shutil

    from facetex.persona import TextureParams, load_persona
    from facetex.persona._stack_cache import stack_cache_folder
    from facetex.persona.stacks import prepare_persona

    p = tmp_path / "copy.persona"
    shutil.copy(persona_path, p)
    tp = TextureParams()
    old = stack_cache_folder(tmp_path / "c", p, tp)
    prepare_persona(load_persona(p), tp, cache=old)
    st = p.stat()
    os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # "rebuilt"
    new = stack_cache_folder(tmp_path / "c", p, tp)
    assert new != old
    prepare_persona(load_persona(p), tp, cache=new)
    assert new.is_dir() and not old.exists()
