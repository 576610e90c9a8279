"""What ``facetex bench transfer`` measures: its methods and presets, the pairs (drawn, or the
issue-22 list), the metrics, the tables' columns and the paper's Table 1 to compare with."""


from __future__ import annotations

from .._methods import NO_TRANSFER, TRANSFER_METHODS
from ..errors import BadInputError
from ._common import (
    Column,
)

DATA_SUBFOLDER = "frl-london"  # inside --data / $FACETEX_DATA (or --data is this folder itself)
METHODS = TRANSFER_METHODS  # one name and one order everywhere: facetex._methods
NONE = NO_TRANSFER  # the content scored as the output ("doing nothing")
PRESETS = ("default", "paper", "preview")
# Figure 3 shows MRF-CNN, FaceTex, Neural Style; the grid uses Table 1's order like every other table
# and page (issue 25: one order for the methods everywhere)
GRID_ORDER = METHODS
ZOOM_ROWS = ("forehead", "left cheek", "upper lip", "chin")  # where hair, shine and stubble show
SAME_PERSON = 0.6  # dlib's same-person threshold for the identity distance

# FaceTex Table 1 (Kaur, Zhang & Dana 2017): means over the five pairs of Figure 3
PAPER_TABLE1 = {
    "gatys": {"E_content": 22.61, "E_style": 369.39, "S_content": 0.89, "S_style": 0.47},
    "mrf": {"E_content": 106.17, "E_style": 191.47, "S_content": 0.70, "S_style": 0.68},
    "facetex": {"E_content": 37.93, "E_style": 295.93, "S_content": 0.76, "S_style": 0.55},
}
METRIC_KEYS = ("E_content", "E_style", "E_content_rms_px", "E_style_rms_px", "S_content", "S_style",
               "identity_content", "identity_style", "S_style_none", "S_style_gain", "detail_output",
               "detail_content", "detail_style", "detail_ratio", "protected_change", "background_change",
               "lowfreq_dE", "lowfreq_dE_max_region", "hair_leakage", "hair_leakage_style", "stubble_output",
               "stubble_content", "stubble_style", "stubble_moved", "coverage", "detail_moved",
               "detail_moved_cheeks", "detail_moved_cheeks_skin", "marks_content", "marks_kept", "marks_style", "marks_arrived")

# Issue 22's pairs (content, style) of FRL London neutral portraits, chosen by looking at them:
# the style has a fringe (F), stubble or a beard (B), shiny skin (S); the two differ in skin
# tone (T) and/or sex (X). The first 10 are the quick set used while iterating.
ISSUE22_PAIRS = (
    ("083", "037"),  # B X: pale young woman <- full-bearded man
    ("010", "003"),  # F: woman <- woman with a heavy fringe
    ("081", "043"),  # S T X: pale blonde woman <- dark-skinned man, shiny forehead
    ("025", "022"),  # B T X: dark-skinned woman <- pale man with a goatee and stubble
    ("087", "067"),  # F X: East Asian woman <- man with a long fringe
    ("063", "061"),  # S T: pale man <- dark-skinned man with shiny skin
    ("090", "092"),  # B X: woman <- bearded man
    ("042", "003"),  # F T X: dark-skinned man <- pale woman with a fringe
    ("030", "021"),  # S X: South-East Asian woman <- bald man, shiny head and forehead
    ("019", "004"),  # B X: young woman <- man with stubble
    ("009", "033"),  # B X: woman <- man with heavy stubble
    ("018", "045"),  # F: man <- man with a fringe
    ("097", "081"),  # F: woman <- woman with a side fringe
    ("006", "042"),  # S X: dark-skinned woman <- dark-skinned man, shiny skin
    ("061", "083"),  # T X: dark-skinned man <- pale woman
    ("062", "009"),  # T: dark-skinned woman <- pale woman
    ("002", "070"),  # B X: woman <- man with stubble
    ("034", "008"),  # T X: East Asian woman <- South Asian man
    ("068", "096"),  # T: pale man <- dark-skinned man
    ("044", "039"),  # X: freckled man <- woman
    ("038", "014"),  # spotted skin woman <- smooth-skinned woman (marks)
    ("004", "005"),  # B: the project's usual pair (stubbled man <- East Asian man)
)
PAIR_LISTS = {"issue22": ISSUE22_PAIRS}

TABLE_COLUMNS = (
    Column("method", "method"),
    Column("n_pairs", "pairs", "d"),
    Column("E_content", "E(xt,xc)", ".2f"),
    Column("E_style", "E(xt,xs)", ".2f"),
    Column("E_content_rms_px", "RMS(xt,xc) px", ".2f"),
    Column("E_style_rms_px", "RMS(xt,xs) px", ".2f"),
    Column("S_content", "S(xt,xc)", ".3f"),
    Column("S_style", "S(xt,xs)", ".3f"),
    Column("S_style_gain", "S gain", "+.3f"),
    Column("identity_content", "id(xt,xc)", ".3f"),
    Column("identity_style", "id(xt,xs)", ".3f"),
    Column("same_identity", f"id(xt,xc)<{SAME_PERSON}", "d"),
    Column("detail_output", "detail", ".2f"),
    Column("detail_ratio", "detail ratio", ".2f"),
    Column("protected_change", "protected Δ", ".2f"),
    Column("background_change", "background Δ", ".2f"),
    Column("prewarp_folds", "folds", "d"),
    Column("lowfreq_dE", "LF ΔE", ".2f"),
    Column("lowfreq_dE_max_region", "LF ΔE max", ".2f"),
    Column("hair_leakage", "hair coh", ".3f"),
    Column("stubble_moved", "stubble moved", "+.2f"),
    Column("coverage", "coverage", ".2f"),
    Column("detail_moved", "detail moved", "+.2f"),
    Column("detail_moved_cheeks", "detail moved cheeks", "+.2f"),
    Column("detail_moved_cheeks_skin", "detail moved cheeks (skin)", "+.2f"),
    Column("marks_kept", "marks kept", ".2f"),
    Column("marks_arrived", "marks arrived", ".2f"),
    Column("time_s", "s / image", ".1f"),
    Column("cpu_s", "CPU s / image", ".1f"),
)
# per pair (the method's row), worst low-frequency ΔE first
PAIR_COLUMNS = (
    Column("pair", "content ← style"), Column("method", "method"),
    Column("lowfreq_dE", "LF ΔE", ".2f"), Column("lowfreq_dE_max_region", "LF ΔE max", ".2f"),
    Column("S_style_gain", "S gain", "+.3f"), Column("identity_content", "id(xt,xc)", ".3f"),
    Column("hair_leakage", "hair coh", ".3f"), Column("hair_leakage_style", "hair coh (style)", ".3f"),
    Column("stubble_output", "specks out", ".2f"), Column("stubble_content", "specks content", ".2f"),
    Column("stubble_style", "specks style", ".2f"), Column("stubble_moved", "stubble moved", "+.2f"),
    Column("coverage", "coverage", ".2f"), Column("detail_moved", "detail moved", "+.2f"),
    Column("detail_moved_cheeks", "moved cheeks", "+.2f"),
    Column("detail_moved_cheeks_skin", "moved cheeks (skin)", "+.2f"), Column("marks_content", "marks c", "d"),
    Column("marks_kept", "kept", ".2f"), Column("marks_style", "marks s", "d"),
    Column("marks_arrived", "arrived", ".2f"), Column("protected_change", "protected Δ", ".2f"),
    Column("background_change", "background Δ", ".2f"), Column("time_s", "s", ".1f"),
)
PAPER_COLUMNS = (Column("method", "method"), Column("E_content", "E(xt,xc)", ".2f"),
                 Column("E_style", "E(xt,xs)", ".2f"), Column("S_content", "S(xt,xc)", ".2f"),
                 Column("S_style", "S(xt,xs)", ".2f"))


def resolve_pair_list(pair_list, portraits) -> list[tuple[str, str]]:
    """(content, style) id pairs from a :data:`PAIR_LISTS` name, a "c:s,c:s" string or a
    sequence of pairs; every id must have a portrait in ``portraits``."""
    if isinstance(pair_list, str):
        if pair_list in PAIR_LISTS:
            pairs = list(PAIR_LISTS[pair_list])
        else:
            try:
                pairs = [tuple(x.split(":")) for x in pair_list.split(",") if x.strip()]
            except ValueError:
                pairs = []
            if not pairs or any(len(p) != 2 for p in pairs):
                raise BadInputError(f"pair list {pair_list!r} is neither one of {', '.join(PAIR_LISTS)} nor "
                                    "'content:style,content:style,...'")
    else:
        pairs = [tuple(p) for p in pair_list]
    pairs = [(str(c).strip(), str(s).strip()) for c, s in pairs]
    missing = sorted({i for p in pairs for i in p if i not in portraits})
    if missing:
        raise BadInputError(f"pair list names people without an NNN_neutral.jpg portrait: {', '.join(missing)}")
    if any(c == s for c, s in pairs):
        raise BadInputError("a pair of the pair list has the same person as content and style")
    return pairs


def parse_methods(methods) -> tuple[str, ...]:
    """Methods from a comma-separated string or a sequence, validated, in Table 1 order."""
    if isinstance(methods, str):
        methods = methods.split(",")
    out = []
    for m in methods:
        m = str(m).strip().lower()
        if not m:
            continue
        if m not in METHODS:
            raise BadInputError(f"unknown method {m!r}: use one or more of {', '.join(METHODS)}")
        if m not in out:
            out.append(m)
    if not out:
        raise BadInputError(f"no method given: use one or more of {', '.join(METHODS)}")
    return tuple(m for m in METHODS if m in out)  # Table 1 order
