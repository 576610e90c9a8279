"""Fixtures of every test: facetex's cache in a temporary folder."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session", autouse=True)
def _own_cache_folder(tmp_path_factory):
    """``$FACETEX_CACHE`` (the dlib detector file, the Live sessions' stack caches, the batch workers'
    downloaded inputs) in a temporary folder for the whole session, so that no test, nor a process
    one starts, writes into the user's cache (~/.cache/facetex). Tests of the cache location itself
    unset or change it with ``monkeypatch``."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FACETEX_CACHE", str(tmp_path_factory.mktemp("facetex_cache")))
        yield
