"""Issue 23: arguments of the wrong type or range to the Python API are a facetex error naming
the argument (not a TypeError, OverflowError or torch's AssertionError), and a stdout that is
closed or full is one error line, not a traceback."""

from __future__ import annotations

import io
import os
import subprocess
import sys

import numpy as np
import pytest

import facetex
from _robust import FACE, OTHER, run_cli
from facetex.errors import BadImageError, BadInputError, BadPersonaError, FacetexError, OutputError

T = {"size": 64, "iters": 2}

API_CASES = {  # name: (call, error class, message)
    "read_image-None": (lambda: facetex.read_image(None), BadImageError, "image file must be a path.*NoneType"),
    "read_image-BytesIO": (lambda: facetex.read_image(io.BytesIO(FACE.read_bytes())), BadImageError,
                           "must be a path.*BytesIO.*PIL.Image.open"),
    "read_image-list": (lambda: facetex.read_image([str(FACE)]), BadImageError, "not list"),
    "load_persona-int": (lambda: facetex.load_persona(3), BadPersonaError, "persona file must be a path.*int"),
    "load_persona-None": (lambda: facetex.load_persona(None), BadPersonaError, "NoneType"),
    "build_persona-None": (lambda: facetex.build_persona(None), BadInputError, "photo folder must be a path"),
    "build_persona-list": (lambda: facetex.build_persona([str(FACE)]), BadInputError, "not list"),
    "puppeteer-None": (lambda: facetex.puppeteer(None, None, "x.mp4"), BadInputError, "must be a path|persona"),
    "transfer-0x0": (lambda: facetex.transfer(np.zeros((0, 0, 3), np.float32), OTHER, **T), BadImageError,
                     r"content image has no pixels \(shape \(0, 0, 3\)\)"),
    "transfer-0xN-uint8": (lambda: facetex.transfer(FACE, np.zeros((0, 7, 3), np.uint8), **T), BadImageError,
                           "style image has no pixels"),
    "seed-2**70": (lambda: facetex.transfer(FACE, OTHER, seed=2**70, **T), BadInputError, r"seed must be from 0 to"),
    "seed-negative": (lambda: facetex.transfer(FACE, OTHER, seed=-1, **T), BadInputError, r"seed must be from 0"),
    "seed-float": (lambda: facetex.transfer(FACE, OTHER, seed=1.5, **T), BadInputError, "seed must be an integer"),
    "device-gpu": (lambda: facetex.transfer(FACE, OTHER, device="gpu", **T), BadInputError,
                   "device 'gpu': unknown device"),
    "device-cuda99": (lambda: facetex.transfer(FACE, OTHER, device="cuda:99", **T), BadInputError,
                      "device cuda:99: (CUDA is not available|only)"),
    "device-None": (lambda: facetex.transfer(FACE, OTHER, device=None, **T), BadInputError, "device None"),
}


@pytest.mark.parametrize("case", sorted(API_CASES))
def test_api_arguments_of_the_wrong_type_or_range(case):
    call, cls, message = API_CASES[case]
    with pytest.raises(cls, match=message) as info:
        call()
    assert isinstance(info.value, FacetexError) and "\n" not in str(info.value)


def test_output_that_is_not_a_path(tmp_path):
    with pytest.raises(OutputError, match="must be a path.*NoneType"):
        facetex.io.write_image(None, np.zeros((40, 40, 3), np.float32))


@pytest.mark.parametrize("seed", [str(2**70), "-1"])
def test_cli_seed_out_of_range_is_a_usage_error(tmp_path, capsys, seed):
    r = run_cli(capsys, "transfer", FACE, OTHER, "-o", tmp_path / "t.png", "--seed", seed, "--size", "64")
    assert r.code == 2 and len(r.lines) == 1 and "--seed" in r.lines[0] and "from 0 to" in r.lines[0], r.err
    assert not (tmp_path / "t.png").exists()


def _facetex_sh(args: str, redirect: str):
    """``python -m facetex ARGS REDIRECT`` in a shell (>&- closes stdout for the child only)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(FACE.parents[3]), os.environ.get("PYTHONPATH", "")]))
    cmd = f"'{sys.executable}' -m facetex {args} {redirect}"
    return subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, timeout=300, env=env)


@pytest.mark.parametrize("redirect, cause", [(">&-", "it is closed"), ("> /dev/full", "No space left")])
@pytest.mark.parametrize("args", ["landmarks '{face}' --json", "-V"])
def test_stdout_closed_or_full_is_one_line(redirect, cause, args):
    if redirect == "> /dev/full" and not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full here")
    r = _facetex_sh(args.format(face=FACE), redirect)
    lines = [line for line in r.stderr.splitlines() if line.strip() and not line.startswith("facetex: warning:")]
    assert r.returncode == 2 and "Traceback" not in r.stderr and "Exception ignored" not in r.stderr, r.stderr
    assert len(lines) == 1 and lines[0].startswith("facetex: error: cannot write to stdout") and cause in lines[0], \
        r.stderr
