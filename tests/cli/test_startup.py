"""The CLI parser must not import torch: only `transfer`, `identity` and friends need it."""

import subprocess
import sys


def test_parser_does_not_import_torch():
    code = ("import sys, facetex.cli as c; c.build_parser(); import facetex.transfer as t; "
            "assert t.METHODS[0] == 'facetex'; print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_transfer_names_resolve_lazily():
    import facetex.transfer as t

    assert callable(t) and callable(t.transfer_with_info) and "mrf_loss" in dir(t)
    try:
        t.no_such_name  # noqa: B018
    except AttributeError as e:
        assert "no_such_name" in str(e)
    else:  # pragma: no cover
        raise AssertionError("unknown names must raise AttributeError")
