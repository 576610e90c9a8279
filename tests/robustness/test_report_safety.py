"""Issue 23: ``facetex report`` reads only regular files inside the run folders it was given
(resolved paths): links, FIFOs, devices and files elsewhere are skipped and listed; nothing
hangs."""

from __future__ import annotations

import base64
import json
import os
import shutil

import pytest

from _robust import bench_run_folder, run_cli, snapshot, tiny_png

SECRET = b"-----BEGIN OPENSSH PRIVATE KEY-----\nb3BlbnNzaC1rZXktdjEAAAAA\n-----END OPENSSH PRIVATE KEY-----\n"
pytestmark = pytest.mark.timeout(120)  # a FIFO that is opened blocks forever: fail instead


@pytest.fixture
def secret(tmp_path):
    d = tmp_path / "private"
    d.mkdir()
    (d / "id_ed25519.png").write_bytes(SECRET)  # named like an image: still not embedded
    return d / "id_ed25519.png"


def _report(capsys, tmp_path, *runs):
    out = tmp_path / "report.html"
    r = run_cli(capsys, "report", *runs, "-o", out)
    return r, (out.read_text() if out.exists() else "")


def _assert_skipped(r, page: str, *names):
    assert r.code == 0, r.err
    assert "Traceback" not in r.err and not r.lines, r.err  # only the warning line
    warn = [line for line in r.err.splitlines() if line.startswith("facetex: warning: skipped")]
    assert len(warn) == 1, r.err
    for n in names:
        assert n in warn[0] and n in page, (n, warn[0])
    assert base64.b64encode(SECRET).decode() not in page and "PRIVATE KEY" not in page


@pytest.mark.parametrize("how", ["symlink", "style_path", "dotdot", "absolute"])
def test_files_outside_the_run_folder_are_not_embedded(tmp_path, capsys, secret, how):
    run = tmp_path / "run"
    if how == "symlink":  # images/*.png a link to a private key
        bench_run_folder(run)
        (run / "images" / "a__b__facetex.png").unlink()
        (run / "images" / "a__b__facetex.png").symlink_to(secret)
        name = "a__b__facetex.png"
    elif how == "style_path":
        bench_run_folder(run, style_path=secret)
        name = secret.name
    elif how == "dotdot":  # "image": "../private/id_ed25519.png"
        bench_run_folder(run, image=f"../{secret.parent.name}/{secret.name}")
        name = secret.name
    else:
        bench_run_folder(run, image=str(secret))
        name = secret.name
    before = snapshot(run)
    r, page = _report(capsys, tmp_path, run)
    _assert_skipped(r, page, name)
    assert snapshot(run) == before and secret.read_bytes() == SECRET


def test_a_symlinked_folder_inside_the_run_is_outside(tmp_path, capsys, secret):
    run = bench_run_folder(tmp_path / "run")
    shutil.rmtree(run / "images")
    (run / "images").symlink_to(secret.parent)  # images/ -> private/
    os.rename(secret, secret.parent / "a__b__facetex.png")
    r, page = _report(capsys, tmp_path, run)
    _assert_skipped(r, page, "a__b__facetex.png")


@pytest.mark.parametrize("what", ["table.md", "images/a__b__facetex.png"])
def test_fifos_and_devices_are_skipped_not_opened(tmp_path, capsys, what):
    run = bench_run_folder(tmp_path / "run")
    (run / what).unlink()
    os.mkfifo(run / what)
    r, page = _report(capsys, tmp_path, run)
    _assert_skipped(r, page, os.path.basename(what))


def test_a_device_table_is_skipped(tmp_path, capsys):
    run = bench_run_folder(tmp_path / "run")
    (run / "table_zero.md").symlink_to("/dev/zero")
    r, page = _report(capsys, tmp_path, run)
    _assert_skipped(r, page, "table_zero.md")


def test_a_fifo_output_with_a_sidecar_is_skipped(tmp_path, capsys):
    """A folder of single-run outputs: one real output, one FIFO named like an output."""
    run = tmp_path / "run"
    tiny_png(run / "a.png")
    rec = {"command": "transfer", "params": {"method": "facetex"}, "inputs": {}}
    (run / "a.png.json").write_text(json.dumps(rec))
    os.mkfifo(run / "b.png")
    (run / "b.png.json").write_text(json.dumps(rec))
    r, page = _report(capsys, tmp_path, run)
    _assert_skipped(r, page, "b.png")


def test_compare_skips_them_too(tmp_path, capsys):
    a, b = bench_run_folder(tmp_path / "a"), bench_run_folder(tmp_path / "b")
    (b / "table.md").unlink()
    os.mkfifo(b / "table.md")
    r = run_cli(capsys, "compare", a, b)
    assert r.code == 0 and "table.md" in r.err and "E_content" in r.out, r.err
