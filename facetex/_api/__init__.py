"""The public Python API: ``facetex.transfer``, ``facetex.build_persona``, ``facetex.puppeteer`` ...

Thin, documented entry points over the implementation subpackages: they take paths, PIL
images or numpy arrays, check them (one clear error naming what is wrong), pass explicit
keyword parameters to the implementation and return numpy arrays (float32 RGB in [0, 1],
(H, W, 3)). Nothing here computes an image itself. One private module per system: inputs,
FaceTex transfer, persona, puppetry.
"""

from ._inputs import ImageLike, Progress, as_image, parse_iters
from ._persona import Mesh, build_persona, load_persona, persona_average, persona_mesh, persona_texture, texture_params
from ._puppet import puppeteer
from ._transfer import transfer, transfer_params, transfer_step_image, transfer_with_info

__all__ = [
    "ImageLike", "Progress", "as_image", "parse_iters", "transfer", "transfer_with_info", "transfer_step_image",
    "transfer_params", "build_persona", "load_persona", "persona_texture", "texture_params", "persona_average",
    "persona_mesh", "Mesh", "puppeteer",
]
