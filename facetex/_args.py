"""Checks of arguments shared by the Python API and the command line (one rule, two callers):
a bad seed or device is one error line before any work, not a torch error after it."""

from __future__ import annotations

import re

import numpy as np

from .errors import BadInputError

__all__ = ["check_seed", "check_device", "SEED_MAX", "DEVICE_PATTERN"]

SEED_MAX = 2**63 - 1  # torch.manual_seed and numpy's generators take any seed up to this
DEVICE_PATTERN = re.compile(r"^(cpu|cuda|cuda:\d+|mps)$")


def check_seed(seed, what: str = "seed") -> int:
    """``seed`` as an int, or BadInputError unless it is an integer from 0 to :data:`SEED_MAX`."""
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, (bool, np.bool_)):
        raise BadInputError(f"{what} must be an integer, not {seed!r}")
    if not 0 <= int(seed) <= SEED_MAX:
        raise BadInputError(f"{what} must be from 0 to {SEED_MAX} (2**63 - 1), not {seed}")
    return int(seed)


def check_device(device, what: str = "device") -> str:
    """``device`` (normalised), or BadInputError unless torch can run on it here: cpu, cuda,
    cuda:N or mps. Called before any input is read."""
    if not isinstance(device, str) or not DEVICE_PATTERN.match(device.strip().lower()):
        raise BadInputError(f"{what} {device!r}: unknown device; use cpu, cuda or cuda:N (a given GPU), or mps")
    device = device.strip().lower()
    if device == "cpu":
        return device
    import torch

    if device.startswith("cuda"):
        if not torch.cuda.is_available():
            raise BadInputError(f"{what} {device}: CUDA is not available in this torch build "
                                f"(torch {torch.__version__}); use cpu")
        if ":" in device and int(device.split(":")[1]) >= torch.cuda.device_count():
            raise BadInputError(f"{what} {device}: only {torch.cuda.device_count()} CUDA device(s) found")
    elif device == "mps":
        mps = getattr(torch.backends, "mps", None)
        if mps is None or not mps.is_available():
            raise BadInputError(f"{what} {device}: Apple MPS is not available here; use cpu")
    return device
