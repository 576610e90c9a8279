# Type stub of the package's lazy exports (facetex/__init__.py loads them on first use): type
# checkers see the real signatures, with their Literal options. Keep in step with _LAZY there
# (tests/api/test_typing.py checks).
from . import bench as bench
from . import geometry as geometry
from . import io as io
from . import landmarks as landmarks
from . import metrics as metrics
from . import nets as nets
from . import persona as persona
from . import puppet as puppet
from . import report as report
from ._api import Mesh as Mesh
from ._api import as_image as as_image
from ._api import build_persona as build_persona
from ._api import load_persona as load_persona
from ._api import parse_iters as parse_iters
from ._api import persona_average as persona_average
from ._api import persona_mesh as persona_mesh
from ._api import persona_texture as persona_texture
from ._api import puppeteer as puppeteer
from ._api import texture_params as texture_params
from ._api import transfer as transfer
from ._api import transfer_step_image as transfer_step_image
from ._api import transfer_with_info as transfer_with_info
from .errors import BadImageError as BadImageError
from .errors import BadInputError as BadInputError
from .errors import BadPersonaError as BadPersonaError
from .errors import BadVideoError as BadVideoError
from .errors import FacetexError as FacetexError
from .errors import MemoryBudgetError as MemoryBudgetError
from .errors import ModelNotFoundError as ModelNotFoundError
from .errors import NoFaceError as NoFaceError
from .errors import OutputError as OutputError
from .io import read_image as read_image
from .io import read_video as read_video
from .io import write_image as write_image
from .io import write_video as write_video
from .landmarks import Face as Face
from .landmarks import detect_face as detect_face
from .landmarks import detect_faces as detect_faces
from .landmarks import face_mesh468 as face_mesh468
from .metrics import identity_distance as identity_distance
from .metrics import landmark_error as landmark_error
from .metrics import texture_similarity as texture_similarity
from .metrics import transfer_metrics as transfer_metrics

__version__: str
__all__: list[str]
