"""JSON files facetex reads back (run folders, batch state) checked against a JSON Schema:
a file of the wrong shape is one error line naming the file and the first wrong field, not a
``TypeError`` deep inside the code that uses it."""

from __future__ import annotations

import json
from typing import Any

from .errors import BadInputError

__all__ = ["check_shape", "parse_json", "OBJECT", "nullable"]

OBJECT = {"type": "object"}
_VALIDATORS: dict[int, Any] = {}
_NAMES = {"object": "a JSON object", "array": "a list", "string": "a string", "number": "a number",
          "integer": "an integer", "boolean": "true or false", "null": "null"}


def nullable(schema: dict) -> dict:
    """``schema`` or null (as a list of types where it can be: clearer messages than anyOf)."""
    if isinstance(schema.get("type"), (str, list)):
        types = [schema["type"]] if isinstance(schema["type"], str) else list(schema["type"])
        return dict(schema, type=types + ["null"])
    return {"anyOf": [{"type": "null"}, schema]}


def _type_name(value) -> str:
    for t, cls in (("null", type(None)), ("boolean", bool), ("integer", int), ("number", float), ("string", str),
                   ("array", list), ("object", dict)):
        if isinstance(value, cls):
            return _NAMES[t]
    return type(value).__name__


def _validator(schema: dict):
    v = _VALIDATORS.get(id(schema))
    if v is None:
        from jsonschema import Draft202012Validator

        v = _VALIDATORS[id(schema)] = Draft202012Validator(schema)
    return v


def check_shape(value, schema: dict, *, path, what: str, error: type = BadInputError, advice: str = "",
                lead: str = ""):
    """``value`` if it matches ``schema``; else ``error`` naming ``path``, the first wrong field,
    what it should be and ``advice`` (one line), after ``lead`` (default "not a ``what``")."""
    from jsonschema.exceptions import best_match

    err = best_match(_validator(schema).iter_errors(value))
    if err is None:
        return value
    where = "the whole file" if err.json_path == "$" else err.json_path.replace("$.", "", 1)
    if err.validator == "type":
        want = err.validator_value if isinstance(err.validator_value, list) else [err.validator_value]
        msg = f"{where} must be {' or '.join(_NAMES.get(t, t) for t in want)}, not {_type_name(err.instance)}"
    else:
        msg = f"{where}: {' '.join(err.message.split())}"
        msg = msg if len(msg) <= 160 else msg[:159] + "…"
    raise error(f"{lead or 'not a ' + what}: {msg}" + (f"; {advice}" if advice else ""), path=path)


def parse_json(text: str | bytes, schema: dict, *, path, what: str, error: type = BadInputError, advice: str = ""):
    """The JSON ``text`` of file ``path``, checked with :func:`check_shape`; one-line errors for
    text that is not UTF-8 or not JSON."""
    advice = f"; {advice}" if advice else ""
    try:
        if isinstance(text, bytes):
            text = text.decode("utf-8")
        value = json.loads(text)
    except UnicodeDecodeError:
        raise error(f"not a UTF-8 text file: not a {what}{advice}", path=path) from None
    except RecursionError:
        raise error(f"not a {what}: nested too deeply{advice}", path=path) from None
    except ValueError as e:
        raise error(f"not a {what}: unreadable JSON ({e}){advice}", path=path) from None
    return check_shape(value, schema, path=path, what=what, error=error, advice=advice[2:])
