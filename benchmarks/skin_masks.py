"""Overlay sheets of the skin masks (facetex.geometry.skin) on a folder of portraits.

    python benchmarks/skin_masks.py --data DIR [--out benchmarks/out/skin_masks] [--limit N]

DIR: a folder of face photos (e.g. FRL London *_neutral.jpg; default $FACETEX_DATA/frl-london).
Writes sheets of 20 face crops: the mask's 0.05 / 0.5 / 0.95 contours (yellow / green / blue)
and the §3.1 skin patches (cyan), and prints per-image mask coverage of each patch."""

import argparse
import os
from pathlib import Path

import cv2
import numpy as np

import facetex
from facetex.geometry.segment import skin_mask
from facetex.landmarks import face_mesh468
from facetex.metrics import skin_patch_frames, working_scale


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(os.environ["FACETEX_DATA"]) / "frl-london" if os.environ.get("FACETEX_DATA") else None
    ap.add_argument("--data", type=Path, default=default, required=default is None)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/out/skin_masks"))
    ap.add_argument("--limit", type=int, default=60)
    a = ap.parse_args()
    files = sorted(p for p in a.data.iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png")
                   and "smiling" not in p.name)[: a.limit]
    a.out.mkdir(parents=True, exist_ok=True)
    cells, cover = [], []
    print(f"{'image':<24} {'forehead':>8} {'l.cheek':>8} {'r.cheek':>8}")
    for f in files:
        img = facetex.read_image(f)
        face = facetex.detect_face(img, source=f)
        p = face.points68
        m = skin_mask(img, p, mesh=face_mesh468(img, face))
        u = (img * 255).astype(np.uint8).copy()
        for lv, col in ((0.05, (255, 255, 0)), (0.5, (0, 255, 0)), (0.95, (0, 0, 255))):
            cs, _ = cv2.findContours((m > lv).astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(u, cs, -1, col, 2)
        side = int(round(100 / working_scale(img.shape)))
        row = []
        for name, A in skin_patch_frames(p, img.shape).items():
            inv = cv2.invertAffineTransform(A)
            corners = np.array([[0, 0], [side, 0], [side, side], [0, side]], float) @ inv[:, :2].T + inv[:, 2]
            cv2.polylines(u, [np.round(corners).astype(np.int32)], True, (0, 255, 255), 2)
            row.append(float(cv2.warpAffine(m, A, (side, side)).mean()))
        cover.append(row)
        print(f"{f.name:<24} {row[0]:8.2f} {row[1]:8.2f} {row[2]:8.2f}")
        x0, y0 = np.maximum(p.min(0).astype(int) - [60, 160], 0)
        x1, y1 = p.max(0).astype(int) + 40
        c = cv2.resize(u[y0:y1, x0:x1], (300, 380), interpolation=cv2.INTER_AREA)
        cv2.putText(c, f.stem[:20], (4, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 0), 2)
        cells.append(c)
    for k in range(0, len(cells), 20):
        part = cells[k:k + 20]
        part += [np.zeros_like(cells[0])] * ((-len(part)) % 5)
        sheet = np.concatenate([np.concatenate(part[i:i + 5], 1) for i in range(0, len(part), 5)], 0)
        out = a.out / f"sheet_{k // 20:02d}.png"
        cv2.imwrite(str(out), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
        print(f"wrote {out}")
    cv = np.array(cover)
    print(f"mean patch coverage: forehead {cv[:, 0].mean():.2f}, cheeks {cv[:, 1:].mean():.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
