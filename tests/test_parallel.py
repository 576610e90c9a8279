"""facetex._parallel: the ast.parse lock (CPython gh-106905 workaround)."""

import ast
import threading

import numpy as np

from facetex._parallel import serialize_ast_parse


def test_ast_parse_is_serialized_and_still_parses_from_many_threads():
    serialize_ast_parse()
    first = ast.parse
    serialize_ast_parse()  # idempotent: not wrapped twice
    assert ast.parse is first and getattr(ast.parse, "_facetex_serialized", False)
    assert ast.literal_eval("{'descr': '<f4', 'shape': (3, 4)}") == {"descr": "<f4", "shape": (3, 4)}
    errors = []

    def work():
        try:
            for _ in range(200):
                ast.literal_eval("{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3)}")
                ast.parse("def f(a, b=1, *c, **d):\n    return [x for x in (a, b) if x]\n")
        except Exception as e:  # noqa: BLE001 - collected and asserted on
            errors.append(e)

    threads = [threading.Thread(target=work) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    # numpy's header parsing goes through it
    import io

    buf = io.BytesIO()
    np.save(buf, np.arange(6, dtype=np.float32).reshape(2, 3))
    buf.seek(0)
    assert np.load(buf).shape == (2, 3)
