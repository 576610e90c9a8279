"""The CLI parser must not import torch: only `transfer`, `identity` and friends need it."""

import subprocess
import sys


def test_parser_does_not_import_torch():
    code = ("import sys, facetex.cli as c; c.build_parser(); from facetex.transfer import methods as t; "
            "import facetex, inspect; assert inspect.isfunction(facetex.transfer); "
            "assert t.METHODS[0] == 'facetex'; print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_transfer_names_resolve_lazily():
    import importlib

    t = importlib.import_module("facetex.transfer")  # the subpackage (facetex.transfer is the function)
    assert callable(t.transfer_with_info) and "mrf_loss" in dir(t)
    try:
        t.no_such_name  # noqa: B018
    except AttributeError as e:
        assert "no_such_name" in str(e)
    else:  # pragma: no cover
        raise AssertionError("unknown names must raise AttributeError")
