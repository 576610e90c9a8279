"""The transfer methods' one name and one order, for every table, figure and page.

The bench, its figures and the report all read these: a method is ``gatys`` / ``mrf`` /
``facetex`` in files and code, "Neural Style" / "MRF-CNN" / "FaceTex" on screen, always in
FaceTex Table 1's column order, with "no transfer" (the content scored as the output) first.
Below the bench and the report (neither imports the other for them), like :mod:`._stats`.
"""

from __future__ import annotations

__all__ = ["PERSONA_ORDER", "TRANSFER_METHODS", "NO_TRANSFER", "METHOD_ORDER", "METHOD_TITLES", "METHOD_COLOURS",
           "method_title", "method_sort_key"]

#: the transfer methods in FaceTex Table 1's order (Neural Style, MRF-CNN, FaceTex)
TRANSFER_METHODS = ("gatys", "mrf", "facetex")
#: the content itself scored as the output: a metric that moves less than its distance from it shows nothing
NO_TRANSFER = "none"
METHOD_ORDER = (NO_TRANSFER, *TRANSFER_METHODS)
METHOD_TITLES = {NO_TRANSFER: "no transfer", "gatys": "Neural Style", "mrf": "MRF-CNN", "facetex": "FaceTex"}
#: FaceTex Figure 4's colours (Neural Style red, MRF-CNN green, FaceTex blue)
METHOD_COLOURS = {NO_TRANSFER: "tab:gray", "gatys": "tab:red", "mrf": "tab:green", "facetex": "tab:blue"}

#: the persona leave-out rows in Tom Hanks Fig. 5's order: static average, weighted average,
#: pre-warped average, the paper's method, ours (bench persona's ROWS are built from it)
PERSONA_ORDER = ("static", "weighted", "prewarp", "paper", "ours")


def method_title(method: str) -> str:
    """The on-screen name of ``method`` (an unknown one is shown as it is)."""
    return METHOD_TITLES.get(method, str(method))


def method_sort_key(method: str, order=METHOD_ORDER) -> tuple:
    """Sort key putting ``order``'s methods first, in that order, and the others by name."""
    return (order.index(method), "") if method in order else (len(order), str(method))
