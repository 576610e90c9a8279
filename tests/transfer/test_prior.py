import numpy as np
import pytest
import torch

from facetex.errors import BadInputError
from facetex.transfer.prior import FacialPrior, FacialPriorGrad, apply_facial_prior, resize_mask


def test_forward_is_identity_and_backward_scales_by_mask():
    g = torch.Generator().manual_seed(0)
    x = torch.rand(2, 3, 5, 6, generator=g, requires_grad=True)
    mask = torch.rand(5, 6, generator=g)
    upstream = torch.randn(2, 3, 5, 6, generator=g)
    y = apply_facial_prior(x, mask)
    assert torch.equal(y, x)
    (y * upstream).sum().backward()
    assert torch.allclose(x.grad, upstream * mask)  # broadcast over batch and channels


def test_per_image_mask_and_zero_mask_freezes_pixels():
    x = torch.ones(2, 3, 4, 4, requires_grad=True)
    mask = torch.ones(2, 1, 4, 4)
    mask[1, :, :2] = 0.0  # top half of the second image frozen
    apply_facial_prior(x, mask).square().sum().backward()
    assert torch.all(x.grad[1, :, :2] == 0) and torch.all(x.grad[1, :, 2:] == 2)
    assert torch.all(x.grad[0] == 2)


def test_gradient_is_mask_times_finite_difference_gradient_float64():
    # The layer's backward is deliberately not its forward's Jacobian (that is the identity).
    # It equals, at x0, the true gradient of v -> f(x0 + m*(v - x0)), which gradcheck verifies
    # against finite differences.
    g = torch.Generator().manual_seed(1)
    x0 = torch.rand(1, 2, 3, 4, generator=g, dtype=torch.float64)
    mask = torch.rand(3, 4, generator=g, dtype=torch.float64)

    def f(y):
        return (y**3).sum() + y.sin().prod()

    def scaled(v):
        return f(x0 + mask * (v - x0))

    v = x0.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(scaled, (v,))
    (expected,) = torch.autograd.grad(scaled(v), v)
    for fn in (lambda y: FacialPriorGrad.apply(y, mask[None, None]), lambda y: apply_facial_prior(y, mask)):
        (got,) = torch.autograd.grad(f(fn(v)), v)
        assert torch.allclose(got, expected, rtol=1e-12, atol=1e-12)


def test_mask_of_wrong_size_is_rejected():
    with pytest.raises(BadInputError):
        apply_facial_prior(torch.zeros(1, 3, 4, 4), torch.ones(5, 4))
    with pytest.raises(BadInputError):
        apply_facial_prior(torch.zeros(1, 3, 4, 4), torch.ones(1, 2, 4, 4))


def test_module_resizes_base_mask_per_level():
    base = np.zeros((8, 8), np.float32)
    base[:, 4:] = 1.0  # right half free
    prior = FacialPrior(base)
    for size in (2, 4, 8):
        x = torch.ones(1, 3, size, size, requires_grad=True)
        prior(x).sum().backward()
        m = resize_mask(torch.from_numpy(base), (size, size))
        assert torch.allclose(x.grad[0, 0], m)
        assert x.grad[0, 0, 0, 0] < x.grad[0, 0, 0, -1]
        if size >= 4:
            assert x.grad[0, 0, 0, 0] == 0 and x.grad[0, 0, 0, -1] == 1  # left frozen, right free
    assert resize_mask(torch.ones(1, 1, 8, 8), (3, 5)).shape == (1, 1, 3, 5)
