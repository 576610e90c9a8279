"""``facetex live`` end to end with a video file, and its one-line errors for bad inputs (nothing written)."""

from __future__ import annotations

import json
import re

import pytest

from facetex.cli import main


def _cli(capsys, *argv):
    capsys.readouterr()
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    lines = [l for l in re.split(r"[\r\n]+", err) if l.strip() and not l.startswith("live:")
             and not l.startswith("facetex: warning:")]
    return code, out, lines


def _one_error(code, lines, *names, cause=""):
    assert code == 2, lines
    assert len(lines) == 1, lines
    assert lines[0].startswith("facetex: error:"), lines
    for n in names:
        assert str(n) in lines[0], lines
    assert re.search(cause, lines[0]), lines


def test_video_file_to_mp4(capsys, tmp_path, live_persona, live_videos):
    from facetex.io import video_info

    out = tmp_path / "live.mp4"
    code, stdout, lines = _cli(capsys, "live", "--puppet", live_persona, "--source", live_videos["face.mp4"],
                               "-o", out, "--size", "96", "--json", "--workers", "thread")
    assert code == 0, lines
    rep = json.loads(stdout)
    assert rep["puppet_frames"] > 0 and rep["output"] == str(out)
    assert {"fps", "dropped", "dropped_pct", "latency_ms_p50", "latency_ms_p95", "first_puppet_s"} <= set(rep)
    info = video_info(out)
    assert (info["width"], info["height"]) == (96, 96) and info["n_frames"] >= rep["puppet_frames"]
    side = (tmp_path / "live.mp4.json").read_text()

    def strict(name):  # Infinity / NaN are not JSON
        raise AssertionError(f"non-standard JSON constant {name} in the sidecar")

    assert json.loads(side, parse_constant=strict)["params"]["live_params"]["warmup"] >= 1


def test_missing_persona(capsys, tmp_path, live_videos):
    missing = tmp_path / "missing.persona"
    code, _, lines = _cli(capsys, "live", "--puppet", missing, "--source", live_videos["face.mp4"],
                          "-o", tmp_path / "o.mp4")
    _one_error(code, lines, missing, cause="not found")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name, cause", [("text.mp4", "not a readable video"), ("gone.mp4", "not found")])
def test_unreadable_source(capsys, tmp_path, live_persona, live_videos, name, cause):
    src = live_videos.get(name, tmp_path / name)
    out = tmp_path / "out"
    out.mkdir()
    code, _, lines = _cli(capsys, "live", "--puppet", live_persona, "--source", src, "-o", out / "o.mp4")
    _one_error(code, lines, src, cause=cause)
    assert list(out.iterdir()) == []


def test_video_without_faces(capsys, tmp_path, live_persona, live_videos):
    out = tmp_path / "out"
    out.mkdir()
    src = live_videos["noface.mp4"]
    code, _, lines = _cli(capsys, "live", "--puppet", live_persona, "--source", src, "-o", out / "o.mp4",
                          "--workers", "thread")
    _one_error(code, lines, src, cause="no usable face")
    assert list(out.iterdir()) == []  # no partial output, no temporary file left


def test_camera_not_available(capsys, tmp_path, live_persona):
    code, _, lines = _cli(capsys, "live", "--puppet", live_persona, "--source", "/dev/video97", "-o",
                          tmp_path / "o.mp4")
    _one_error(code, lines, "/dev/video97", cause="camera not available")
    assert list(tmp_path.iterdir()) == []


def test_no_display_without_output(capsys, monkeypatch, live_persona, live_videos):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    code, _, lines = _cli(capsys, "live", "--puppet", live_persona, "--source", live_videos["face.mp4"])
    _one_error(code, lines, cause="no display")


def test_damaged_persona(capsys, tmp_path, live_persona, live_videos):
    bad = tmp_path / "cut.persona"
    raw = live_persona.read_bytes()
    bad.write_bytes(raw[: len(raw) // 3])
    out = tmp_path / "out"
    out.mkdir()
    code, _, lines = _cli(capsys, "live", "--puppet", bad, "--source", live_videos["face.mp4"], "-o", out / "o.mp4")
    _one_error(code, lines, bad, cause="corrupt|truncated|damaged")
    assert list(out.iterdir()) == []
