"""Lazy public names of a package (PEP 562, like scikit-image's lazy loading): a name is
imported from its private module on first use, so importing one submodule does not load
them all."""

from __future__ import annotations

import importlib


def lazy_attributes(package: str, namespace: dict, names: dict[str, str]):
    """(``__getattr__``, ``__dir__``) for the package ``package`` whose module dict is
    ``namespace``; ``names`` maps each public name to its submodule (relative, no dot)."""

    def __getattr__(name: str):
        mod = names.get(name)
        if mod is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f".{mod}", package), name)
        namespace[name] = value
        return value

    def __dir__():
        return sorted(set(namespace) | set(namespace.get("__all__", ())))

    return __getattr__, __dir__
