"""Feature networks as frozen, differentiable torch modules with named intermediate outputs.

Every network takes (N, 3, H, W) RGB in [0, 1] (its own normalisation is applied inside)
and offers ``features(x, layers) -> {name: tensor}``, stopping at the deepest layer asked.
"""

from .chip import face_chip, face_chip_details, face_chip_matrix, face_chip_tensor
from .dlib_resnet import (
    LAYER_NAMES as FACE_RESNET_LAYERS,
    SAME_PERSON_THRESHOLD,
    FaceRecognitionNet,
    face_descriptor,
    identity_distance,
)
from .effnet import EfficientNetLite0Features
from .vgg import VGG19Features, hub_weights_path

__all__ = [
    "FaceRecognitionNet", "FACE_RESNET_LAYERS", "SAME_PERSON_THRESHOLD", "face_descriptor", "identity_distance",
    "face_chip", "face_chip_details", "face_chip_matrix", "face_chip_tensor",
    "EfficientNetLite0Features", "VGG19Features", "hub_weights_path",
]
