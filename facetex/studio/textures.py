"""``python -m facetex.studio.textures PERSONA OUT_DIR PHOTO...`` — the Persona page's textures.

The persona's average face (stage d) and, for each reference photo, the expression texture the
persona synthesizes for that photo's expression (:func:`facetex.persona_texture`, the same blend
as ``facetex persona texture --like PHOTO``), written as ``OUT_DIR/average.png`` and
``OUT_DIR/texture_<k>.png``. One process for all of them: the persona is loaded once. A failure
is one ``facetex: error: ...`` line (exit 2), like the CLI's; a photo without a usable face
gets no texture (the page shows the others).
"""

from __future__ import annotations

import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    """Write the average and one texture per photo; progress as a tqdm bar on stderr.

    Parameters
    ----------
    argv : list of str, optional
        ``PERSONA OUT_DIR PHOTO...`` (default: the process's arguments).

    Returns
    -------
    int
        The exit code: 0, or the error's (2) after its one line on stderr.
    """
    from tqdm import tqdm

    from .. import load_persona, persona_average, persona_texture
    from ..errors import FacetexError, NoFaceError
    from ..io import write_image

    argv = sys.argv[1:] if argv is None else argv
    if len(argv) < 2:
        print("usage: python -m facetex.studio.textures PERSONA OUT_DIR PHOTO...", file=sys.stderr)
        return 2
    persona_path, out, photos = argv[0], Path(argv[1]), argv[2:]
    try:
        out.mkdir(exist_ok=True)
        persona = load_persona(persona_path)
        with tqdm(total=1 + len(photos), desc="textures", unit="image", file=sys.stderr) as bar:
            write_image(out / "average.png", persona_average(persona, stage="d"))
            bar.update(1)
            for k, photo in enumerate(photos):
                try:
                    write_image(out / f"texture_{k}.png", persona_texture(persona, like=photo))
                except NoFaceError as e:  # this photo only: the others are still worth seeing
                    tqdm.write(f"facetex: warning: {e}", file=sys.stderr)
                bar.update(1)
    except FacetexError as e:
        print(f"facetex: error: {e}", file=sys.stderr)
        return e.exit_code
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
