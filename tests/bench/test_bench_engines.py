"""The benches on an engine: the same numbers as the sequential run (slow: real puppetry)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from _photos import build_tiny_persona

from facetex._resources import sample_path
from facetex.io import read_image, write_video

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def puppet_data(tmp_path_factory):
    """A tiny persona file (8 jittered copies of frl_004, 96 x 120 canonical frame) and two 6-frame driver clips."""
    persona_file = build_tiny_persona(tmp_path_factory.mktemp("persona") / "p.persona", seed=0)
    drivers = tmp_path_factory.mktemp("drivers")
    for k, name in enumerate(("frl_005_neutral", "frl_003_neutral")):
        img = cv2.resize(read_image(sample_path(f"{name}.jpg")), (200, 200), interpolation=cv2.INTER_AREA)
        write_video(drivers / f"clip{k}.mp4", [np.roll(img, (i % 3) - 1, axis=1) for i in range(6)], 10.0)
    return drivers, persona_file


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or a == pytest.approx(b, rel=1e-5, abs=1e-6)
    return a == b


def test_bench_puppet_on_two_workers_matches_the_sequential_run(puppet_data, tmp_path):
    from facetex.batch import LocalEngine
    from facetex.bench.puppet import COLUMNS, run_bench_puppet

    drivers, persona = puppet_data
    seq = run_bench_puppet(drivers, persona, tmp_path / "seq", size=96)
    with LocalEngine(2, threads=1) as eng:
        par = run_bench_puppet(drivers, persona, tmp_path / "par", size=96, engine=eng)
    assert [r["clip"] for r in par["rows"]] == [r["clip"] for r in seq["rows"]] == ["clip0", "clip1"]
    for a, b in zip(seq["rows"], par["rows"]):
        for c in COLUMNS:
            if c.key == "fps":  # a timing
                continue
            assert _same(a[c.key], b[c.key]), (a["clip"], c.key, a[c.key], b[c.key])
    assert par["partial"] == seq["partial"]
    assert [r["driver_glasses"] for r in seq["rows"]] == [False, False]  # bare faces: no rims kept
    assert (tmp_path / "par" / "p" / "clip0_side_by_side.mp4").is_file() and (tmp_path / "par" / "table.md").is_file()
    assert [r["run"] for r in par["rows"]] == ["p/clip0", "p/clip1"]
