"""One-line errors of the Ray engine that need no running Ray (fast)."""

from __future__ import annotations

import socket
import sys

import pytest

from facetex._resources import sample_path
from facetex.cli import main


def _args(tmp_path, *extra):
    return ["batch", "transfer", "--contents", str(sample_path()), "--styles", str(sample_path()), "--out",
            str(tmp_path / "o"), "--engine", "ray", *extra]


def test_ray_missing_is_one_line_saying_what_to_install(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails as if it were not installed
    assert main(_args(tmp_path)) == 2
    err = capsys.readouterr().err.strip()
    assert err == "facetex: error: --engine ray needs Ray: pip install 'facetex[ray]' (or pip install 'ray[client]')"
    assert not (tmp_path / "o").exists()  # no output folder


@pytest.mark.parametrize("scheme", ["", "ray://"])
def test_unreachable_cluster_is_one_line_naming_the_address(tmp_path, capsys, scheme):
    pytest.importorskip("ray")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    address = f"{scheme}127.0.0.1:{port}"
    assert main(_args(tmp_path, "--address", address)) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"facetex: error: cannot reach the Ray cluster at {address}: Connection refused (is `ray start "
                   "--head` running there, and the port open?)")
    assert not (tmp_path / "o").exists()  # the engine starts before the output folder is made


def test_bad_address_syntax(tmp_path, capsys):
    pytest.importorskip("ray")
    assert main(_args(tmp_path, "--address", "nowhere")) == 2
    assert "give auto, HOST:PORT or ray://HOST:PORT" in capsys.readouterr().err
