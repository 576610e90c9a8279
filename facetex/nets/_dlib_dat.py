"""Reader for dlib's binary serialization of DNN models (``*.dat``), hand-written.

No library reads dlib's format without dlib itself, so this follows dlib's
``serialize.h`` / ``dnn/core.h`` / ``dnn/layers.h`` semantics:

* integers: one control byte (low nibble = number of bytes, bit 0x80 = negative),
  then that many little-endian magnitude bytes;
* floats: an integer mantissa and an integer exponent, value = mantissa * 2**exponent;
* strings: integer length, then the bytes; bools: the character '0' or '1';
* tensors (version 2): num_samples, k, nr, nc, then raw little-endian float32;
* a network: the loss layer first, then one version integer per wrapper (add_layer,
  tag, skip) from the output down to the input, then the input layer, then each
  computational layer's details from the input upward, each followed by its
  add_layer bookkeeping (three bools and two or three, usually empty, tensors).

Tag and skip layers write nothing but a version, so the wiring of a network is not
in the file: :func:`read_dnn` returns the flat list of layers and the caller
supplies the architecture.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ModelNotFoundError


class DatFormatError(ModelNotFoundError):
    """A dlib .dat file does not have the expected layout."""


@dataclass
class Layer:
    kind: str  # "con", "bn", "affine", "relu", "max_pool", "avg_pool", "add_prev", "fc"
    version: str
    params: dict = field(default_factory=dict)


class _Reader:
    def __init__(self, data: bytes, path):
        self.data = data
        self.pos = 0
        self.path = path

    def fail(self, what: str):
        raise DatFormatError(f"unexpected dlib model layout at byte {self.pos} ({what}): "
                             "reinstall face-recognition-models", path=self.path)

    def need(self, n: int) -> None:
        if self.pos + n > len(self.data):
            self.fail("file ends early")

    def int(self) -> int:
        self.need(1)
        ctrl = self.data[self.pos]
        n = ctrl & 0x0F
        if ctrl & 0x70 or n > 8:
            self.fail(f"bad integer control byte {ctrl:#x}")
        self.need(1 + n)
        v = int.from_bytes(self.data[self.pos + 1:self.pos + 1 + n], "little")
        self.pos += 1 + n
        return -v if ctrl & 0x80 else v

    def float(self) -> float:
        mantissa, exponent = self.int(), self.int()
        special = {32000: math.inf, 32001: -math.inf, 32002: math.nan}
        return special[exponent] if exponent in special else math.ldexp(mantissa, exponent)

    def str(self) -> str:
        n = self.int()
        self.need(n)
        s = self.data[self.pos:self.pos + n]
        self.pos += n
        return s.decode("latin-1")

    def peek_str(self) -> str | None:
        """The string starting here, or None if the bytes here cannot be a short string."""
        ctrl = self.data[self.pos] if self.pos < len(self.data) else 0
        if ctrl not in (1, 2):
            return None
        save = self.pos
        try:
            n = self.int()
            s = self.data[self.pos:self.pos + n]
            ok = 3 <= n <= 64 and all(32 < c < 127 for c in s)
            return s.decode("ascii") if ok else None
        finally:
            self.pos = save

    def bool(self) -> bool:
        self.need(1)
        c = self.data[self.pos:self.pos + 1]
        if c not in (b"0", b"1"):
            self.fail("bad bool")
        self.pos += 1
        return c == b"1"

    def tensor(self) -> np.ndarray:
        if self.int() != 2:
            self.fail("tensor version")
        shape = tuple(self.int() for _ in range(4))
        n = int(np.prod(shape))
        if min(shape) < 0:
            self.fail("negative tensor size")
        self.need(4 * n)
        a = np.frombuffer(self.data, dtype="<f4", count=n, offset=self.pos).reshape(shape)
        self.pos += 4 * n
        return a.astype(np.float32)

    def alias(self) -> tuple[int, ...]:
        if self.int() != 1:
            self.fail("alias tensor version")
        return tuple(self.int() for _ in range(4))


def _read_layer(r: _Reader) -> Layer:
    v = r.str()
    if v in ("con_4", "con_5", "con_6"):
        params = r.tensor().ravel()
        p = dict(num_filters=r.int(), nr=r.int(), nc=r.int(), stride_y=r.int(), stride_x=r.int(),
                 padding_y=r.int(), padding_x=r.int())
        fshape, bshape = r.alias(), r.alias()
        for _ in range(4):  # learning-rate / weight-decay multipliers
            r.float()
        p["use_bias"] = r.bool() if v != "con_4" else True
        if v == "con_6":
            r.bool()  # use_relu (fused relu, only an optimisation)
        nf = int(np.prod(fshape))
        p["weight"] = params[:nf].reshape(fshape[:4])
        p["bias"] = params[nf:nf + int(np.prod(bshape))] if p["use_bias"] else None
        return Layer("con", v, p)
    if v in ("bn_con2", "bn_fc2"):
        params = r.tensor().ravel()
        gshape, bshape = r.alias(), r.alias()
        for _ in range(2):  # means, invstds of the last training batch
            r.tensor()
        p = dict(running_mean=r.tensor().ravel(), running_var=r.tensor().ravel())
        r.int(), r.int()  # num_updates, running_stats_window_size
        for _ in range(4):
            r.float()
        p["eps"] = r.float()
        ng = int(np.prod(gshape))
        p["gamma"], p["beta"] = params[:ng], params[ng:ng + int(np.prod(bshape))]
        return Layer("bn", v, p)
    if v in ("affine_", "affine_2"):
        params = r.tensor().ravel()
        gshape, bshape = r.alias(), r.alias()
        mode = r.int()
        disabled = r.bool() if v == "affine_2" else False
        ng = int(np.prod(gshape))
        return Layer("affine", v, dict(gamma=params[:ng], beta=params[ng:ng + int(np.prod(bshape))],
                                       mode=mode, disabled=disabled))
    if v in ("relu_", "relu_2"):
        return Layer("relu", v, dict(disabled=r.bool() if v == "relu_2" else False))
    if v in ("max_pool_2", "avg_pool_2"):
        keys = ("nr", "nc", "stride_y", "stride_x", "padding_y", "padding_x")
        return Layer(v[:-2], v, {k: r.int() for k in keys})
    if v == "add_prev_":
        return Layer("add_prev", v)
    if v in ("fc_2", "fc_3"):
        p = dict(num_outputs=r.int(), num_inputs=r.int())
        params = r.tensor().ravel()
        wshape, bshape = r.alias(), r.alias()
        p["bias_mode"] = r.int()
        for _ in range(4):
            r.float()
        p["use_bias"] = r.bool() if v == "fc_3" else True
        nw = int(np.prod(wshape))
        p["weight"] = params[:nw].reshape(wshape[0], wshape[1])  # (num_inputs, num_outputs)
        p["bias"] = params[nw:nw + int(np.prod(bshape))] if p["bias_mode"] == 0 and p["use_bias"] else None
        return Layer("fc", v, p)
    r.pos -= len(v) + 2
    r.fail(f"unknown layer version {v!r}")


@dataclass
class DnnFile:
    loss: str
    loss_params: dict
    input: dict
    layers: list[Layer]


def read_dnn(path: str | Path) -> DnnFile:
    """Parse a dlib DNN ``.dat`` (loss_metric + input_rgb_image networks) into its layers,
    input to output."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise ModelNotFoundError(f"cannot read the dlib model ({e.strerror}): reinstall "
                                 "face-recognition-models", path=path) from None
    r = _Reader(data, path)
    if r.int() != 1:
        r.fail("loss layer version")
    loss = r.str()
    if loss != "loss_metric_2" and loss != "loss_metric_":
        r.fail(f"loss {loss!r}")
    loss_params = dict(margin=r.float(), dist_thresh=r.float())
    # wrapper versions from the output down to the input
    while (s := r.peek_str()) is None or not s.startswith("input"):
        r.int()
    inp_version = r.str()
    if inp_version not in ("input_rgb_image", "input_rgb_image_sized"):
        r.fail(f"input layer {inp_version!r}")
    inp = dict(avg_red=r.float(), avg_green=r.float(), avg_blue=r.float())
    if inp_version == "input_rgb_image_sized":
        inp["nr"], inp["nc"] = r.int(), r.int()
    layers = []
    first = True
    while r.pos < len(data):
        layers.append(_read_layer(r))
        for _ in range(3):  # setup_called, gradient_input_is_stale, output/gradient disabled
            r.bool()
        r.tensor(), r.tensor()  # x_grad, cached_output
        if r.data[r.pos:r.pos + 2] == b"\x01\x02":  # params_grad / grad_final (version 2 wrappers)
            r.tensor()
        if first:  # the input's add_layer (version 3) also stores _sample_expansion_factor
            if r.pos < len(data) and r.peek_str() is None:
                r.int()
            first = False
    return DnnFile(loss, loss_params, inp, layers)
