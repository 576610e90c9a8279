"""Make the documentation gallery's images from the shared data (FaceTex pairs with native-resolution
cheek crops, a persona's expression textures, a puppet clip as an animated WebP).

    python docs/make_gallery.py --data DATA --persona PERSON.persona [--out docs/gallery]

DATA holds frl-london/ and grid/ (default $FACETEX_DATA); PERSON.persona is built with
``facetex persona build DATA/lfw/<person>``; its photo folder gives the target expressions. The images
are small JPEG / WebP files (together < 2 MB), fit to commit with the docs."""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

import facetex

PAIRS = (("042", "003"), ("006", "042"), ("025", "022"))  # skin tone, sex and age differ within each pair
THUMB = 200


def _u8(img):
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def _thumb(img, side=THUMB):
    h, w = img.shape[:2]
    s = side / max(h, w)
    return cv2.resize(_u8(img), (round(w * s), round(h * s)), interpolation=cv2.INTER_AREA)


def _pad(img, h, w):
    out = np.full((h, w, 3), 255, np.uint8)
    out[:img.shape[0], :img.shape[1]] = img
    return out


def facetex_pairs(data: Path, out: Path) -> None:
    rows = []
    for c, s in PAIRS:
        cp, sp = data / "frl-london" / f"{c}_neutral.jpg", data / "frl-london" / f"{s}_neutral.jpg"
        content = facetex.read_image(cp)
        result = facetex.transfer(content, sp, seed=0)
        p = facetex.detect_face(content).points68
        eye = float(np.linalg.norm(p[36] - p[45]))
        cx, cy = ((p[2] + p[31]) / 2 + [-0.1 * eye, -0.15 * eye]).astype(int)
        r = int(0.25 * eye)
        crop = lambda im: cv2.resize(_u8(im[cy - r:cy + r, cx - r:cx + r]), None, fx=2, fy=2,  # noqa: E731
                                     interpolation=cv2.INTER_NEAREST)
        tiles = [_thumb(content), _thumb(result), _thumb(facetex.read_image(sp)), crop(content), crop(result)]
        h = max(t.shape[0] for t in tiles)
        rows.append(np.concatenate([_pad(t, h, t.shape[1]) for t in tiles], 1))
    w = max(r.shape[1] for r in rows)
    sheet = np.concatenate([_pad(r, r.shape[0] + 6, w) for r in rows], 0)
    Image.fromarray(sheet).save(out / "facetex_pairs.jpg", quality=88)


def persona_textures(persona_path: Path, photos: list[Path], out: Path) -> None:
    persona = facetex.load_persona(persona_path)
    tiles = [_thumb(facetex.persona_average(persona, stage="d"), 180)]
    for ph in photos:
        tiles += [_thumb(facetex.read_image(ph), 180), _thumb(facetex.persona_texture(persona, like=ph), 180)]
    h = max(t.shape[0] for t in tiles)
    Image.fromarray(np.concatenate([_pad(t, h, t.shape[1] + 4) for t in tiles], 1)).save(
        out / "persona_textures.jpg", quality=88)


def puppet_clip(clip: Path, persona_path: Path, out: Path, frames: int = 50) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        mp4 = Path(tmp) / "p.mp4"
        facetex.puppeteer(clip, persona_path, mp4, side_by_side=True, size=192, max_frames=frames)
        imgs, fps = facetex.read_video(mp4)
    pil = [Image.fromarray(_u8(f)) for f in imgs]
    pil[0].save(out / "puppet.webp", save_all=True, append_images=pil[1:], duration=int(1000 / fps), loop=0,
                quality=70)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=os.environ.get("FACETEX_DATA"), help="data folder (default $FACETEX_DATA)")
    ap.add_argument("--persona", required=True, help="a .persona file")
    ap.add_argument("--photos", nargs="*", default=None, help="photos whose expressions to synthesise "
                                                               "(default: 3 from DATA/lfw/George_W_Bush)")
    ap.add_argument("--clip", default=None, help="driver clip (default DATA/grid/bbaf2n.mpg)")
    ap.add_argument("--out", default=str(Path(__file__).parent / "gallery"))
    a = ap.parse_args()
    if not a.data:
        ap.error("give --data or set FACETEX_DATA")
    data, out = Path(a.data), Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    photos = a.photos or [data / "lfw" / "George_W_Bush" / f"George_W_Bush_{k:04d}.jpg" for k in (3, 12, 45)]
    facetex_pairs(data, out)
    persona_textures(Path(a.persona), [Path(p) for p in photos], out)
    puppet_clip(Path(a.clip or data / "grid" / "bbaf2n.mpg"), Path(a.persona), out)
    for f in sorted(out.iterdir()):
        print(f"wrote {f} ({f.stat().st_size / 1024:.0f} KiB)")


if __name__ == "__main__":
    main()
