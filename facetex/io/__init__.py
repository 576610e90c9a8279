"""Image and video I/O: robust reading, atomic writing, PyAV video.

Images leave this module as float32 RGB in [0, 1], shape (H, W, 3). Every failure a
user can cause raises :class:`BadImageError` / :class:`BadVideoError` /
:class:`OutputError` with ``path`` set and a one-line cause.

The implementation is in private modules by topic: :mod:`._read` (images in),
:mod:`._convert` (pixel types), :mod:`._files` (input files, ``.npz`` headers),
:mod:`._atomic` (the commit protocol of every output), :mod:`._write` (images and JSON out)
and :mod:`._video`. Use the names here.
"""

from __future__ import annotations

from ._atomic import (
    IMAGE_EXTENSIONS,
    VIDEO_EXTENSIONS,
    atomic_path,
    check_output_path,
    check_outputs,
    committed_outputs,
    temp_tag,
    write_files,
)
from ._convert import LUMA_BT601, check_float_pixels, linear_to_srgb, srgb_to_linear, to_float32, to_uint8
from ._files import (
    as_path,
    check_input_dir,
    check_input_file,
    npz_members,
    read_npy_header,
    read_regular,
)
from ._read import (
    DETECT_MAX_PIXELS,
    IMAGE_MEMORY_BUDGET,
    MAX_IMAGE_PIXELS,
    ImageLike,
    as_image,
    image_args,
    read_image,
    read_image_reduced,
    read_image_uint8,
)
from ._video import (
    display_turns,
    iter_video_frames,
    read_video,
    transcode_audio,
    video_info,
    write_video,
)
from ._write import encode_image, encode_json, write_image, write_json

__all__ = [  # in the order of the reference page
    "ImageLike", "as_image", "image_args", "to_float32", "check_float_pixels", "to_uint8", "LUMA_BT601", "srgb_to_linear",
    "linear_to_srgb", "as_path",
    "check_input_file", "read_regular", "check_input_dir", "MAX_IMAGE_PIXELS", "DETECT_MAX_PIXELS",
    "IMAGE_MEMORY_BUDGET", "read_image", "read_image_reduced", "read_image_uint8", "IMAGE_EXTENSIONS",
    "VIDEO_EXTENSIONS", "committed_outputs", "check_output_path", "check_outputs", "temp_tag", "write_files",
    "atomic_path", "encode_image", "write_image", "encode_json", "write_json", "read_npy_header",
    "npz_members", "video_info", "display_turns", "iter_video_frames", "read_video", "transcode_audio", "write_video",
]
