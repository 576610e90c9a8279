"""IoU of the face segmentation (facetex.geometry.segment.segment_face) against hand-drawn outlines.

    python benchmarks/skin_segmentation.py [--data DIR] [--sheet OUT.png]

DIR: the FRL London portraits (default $FACETEX_DATA/frl-london). The outlines are in
``benchmarks/skin_segmentation.json`` (hair: hairline, fringe and sides; beard: beard, moustache,
stubble; ignore: ambiguous, e.g. a shaved scalp), drawn by hand on 2x views of 22 portraits with a
grid. The reference labels, inside the head region searched (landmarks) minus the grown features
(eyes, brows, lips, nostrils: labelled from landmarks in both, so not scored) and minus the ignore
outlines: hair = inside a hair outline, beard = inside a beard outline, other = the studio's grey
background (saturation < 0.12 and value > 0.55), skin = the rest. Prints IoU per class and image
and pooled over all images (intersections and unions summed), and optionally an overlay sheet
(reference outlines over the predicted labels).
"""

import argparse
import json
import os
import time
from pathlib import Path

import cv2
import numpy as np

import facetex
from facetex.geometry.segment import LABELS, head_region_mask, segment_face
from facetex.geometry.skin import feature_mask
from facetex.landmarks import face_mesh468

HERE = Path(__file__).resolve().parent


def _fill(polys, shape) -> np.ndarray:
    m = np.zeros(shape, np.uint8)
    for poly in polys:
        cv2.fillPoly(m, [np.round(np.asarray(poly) * 16).astype(np.int32)], 1, cv2.LINE_8, 4)
    return m.astype(bool)


def reference(img, p, mesh, ann):
    """(labels, scored) of the hand outlines: labels uint8 (LABELS values), scored bool."""
    h, w = img.shape[:2]
    scored = head_region_mask(p, (h, w), mesh=mesh) & ~feature_mask(p, (h, w)) & ~_fill(ann.get("ignore", []), (h, w))
    mx = img.max(-1)
    grey = ((mx - img.min(-1)) / (mx + 1e-3) < 0.12) & (mx > 0.55)
    lab = np.full((h, w), LABELS["skin"], np.uint8)
    lab[_fill(ann.get("beard", []), (h, w))] = LABELS["beard"]
    lab[_fill(ann.get("hair", []), (h, w))] = LABELS["hair"]
    lab[grey] = LABELS["other"]
    return lab, scored


def predicted(seg) -> np.ndarray:
    lab = np.full(seg.labels.shape, LABELS["other"], np.uint8)
    lab[seg.hair] = LABELS["hair"]
    lab[seg.beard] = LABELS["beard"]
    lab[seg.skin] = LABELS["skin"]  # highlights are skin
    return lab


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(os.environ["FACETEX_DATA"]) / "frl-london" if os.environ.get("FACETEX_DATA") else None
    ap.add_argument("--data", type=Path, default=default, required=default is None)
    ap.add_argument("--sheet", type=Path, default=None, help="write an overlay sheet here")
    a = ap.parse_args()
    anns = json.loads((HERE / "skin_segmentation.json").read_text())["images"]
    classes = ("skin", "hair", "beard")
    inter = {c: 0 for c in classes}
    union = {c: 0 for c in classes}
    cells, cpu = [], []
    print(f"{'image':<8}" + "".join(f"{c:>8}" for c in classes) + f"{'cpu s':>7}")
    for name, ann in anns.items():
        f = a.data / f"{name}_neutral.jpg"
        img = facetex.read_image(f)
        face = facetex.detect_face(img, source=f)
        p = face.points68
        mesh = face_mesh468(img, face)
        ref, scored = reference(img, p, mesh, ann)
        t = time.process_time()
        pred = predicted(segment_face(img, p, mesh=mesh))
        cpu.append(time.process_time() - t)
        row = []
        for c in classes:
            r, q = (ref == LABELS[c]) & scored, (pred == LABELS[c]) & scored
            i, u = int((r & q).sum()), int((r | q).sum())
            inter[c] += i
            union[c] += u
            row.append(f"{i / u:8.2f}" if (r.any() or q.sum() > 200) and u else f"{'-':>8}")
        print(f"{name:<8}" + "".join(row) + f"{cpu[-1]:7.2f}")
        if a.sheet:
            u8 = (img * 255).astype(np.uint8)
            col = {LABELS["skin"]: (0, 200, 0), LABELS["hair"]: (220, 0, 0), LABELS["beard"]: (160, 0, 255)}
            ov = u8.copy()
            for v, c in col.items():
                ov[(pred == v) & scored] = c
            u8 = (0.6 * u8 + 0.4 * ov).astype(np.uint8)
            for v, c in col.items():
                cs, _ = cv2.findContours(((ref == v) & scored).astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
                cv2.drawContours(u8, cs, -1, (255, 255, 255) if v == LABELS["skin"] else c, 2)
            x0, y0 = np.maximum(p.min(0).astype(int) - [60, 200], 0)
            x1, y1 = p.max(0).astype(int) + 40
            cell = cv2.resize(u8[y0:y1, x0:x1], (240, 300), interpolation=cv2.INTER_AREA)
            cv2.putText(cell, name, (4, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 0), 2)
            cells.append(cell)
    print(f"{'pooled':<8}" + "".join(f"{inter[c] / max(union[c], 1):8.2f}" for c in classes)
          + f"{np.mean(cpu):7.2f}")
    if a.sheet and cells:
        cells += [np.zeros_like(cells[0])] * ((-len(cells)) % 6)
        sheet = np.concatenate([np.concatenate(cells[k:k + 6], 1) for k in range(0, len(cells), 6)], 0)
        cv2.imwrite(str(a.sheet), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
        print(f"wrote {a.sheet}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
