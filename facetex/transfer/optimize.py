"""Generic multi-resolution pixel optimiser (CNNMRF / FaceTex Eq. 5 solver).

As in CNNMRF's ``transfer_CNNMRF_wrapper.lua``: level sizes are ceil(size · scale) with the
scale doubling per level up to 1; level 0 starts from the init image resized down, each
next level from the previous result upsampled bilinearly; the loss targets (resized
content/style/masks, style patches) are rebuilt per level by the caller's ``loss_builder``.

Choices and how they differ from the authors' code (``mylib/myoptimizer.lua``):

- L-BFGS is ``torch.optim.LBFGS``'s algorithm (a port of torch7 ``optim.lbfgs``, which mylbfgs
  copies; run by ``_lbfgs.LBFGS``, the same iterates without torch's optimiser base class),
  history 25 (``nCorrection=25``). ``line_search="strong_wolfe"`` (default) is robust to the
  loss scale; ``line_search=None`` is CNNMRF's behaviour: no line search, step
  min(1, 1/‖g‖₁) first and 1 after. CNNMRF sets tolFun = tolX = 0 and always runs every
  iteration. The MRF loss re-matches patches on every evaluation, so it is piecewise smooth
  and a strong-Wolfe search can return a zero step far from a minimum (torch's LBFGS then
  stops: on the paper preset 36–47 of 200 iterations ran). Here a level runs its
  ``iters`` iterations (within ``eval_budget`` × iters loss evaluations; 2 by default, the
  default preset keeps torch's 1.25): when LBFGS stops early it is restarted
  with an empty history (a steepest-descent step); the level ends early only on the
  documented convergence test: max |gradient| ≤ ``tolerance_grad`` (1e-7), two restarts
  in a row that lower the loss by less than 1e-7 relative, or (``converge=(k, rtol)``, the
  paper preset) a best loss that fell by less than ``rtol`` over the last ``k`` iterations
  or the last ⌈``eval_budget`` · k⌉ loss evaluations, whichever come first
  (``info["levels"][k]["stop"]``): near a kink of the MRF loss (its matches flip) one
  strong-Wolfe search can take 10–17 evaluations for a 0.3 % decrease, and on the default
  preset's coarsest level such searches were half of its evaluations.
- torch's L-BFGS evaluates its start point at every ``step()`` call; on a restart or a next
  convergence chunk that is the point its line search evaluated last, so that evaluation
  (loss and gradient) is reused, not recomputed (the same numbers, one evaluation fewer).
- ``change_mask``: optimise ``z`` with ``x = x₀ + m ⊙ z`` instead of ``x`` (a hard
  constraint: pixels with m = 0 never change, whatever the curvature pairs do — a gradient
  mask > 0 alone is only a preconditioner under L-BFGS; findings: a pixel scaled by 0.05
  moved 0.666 vs 0.658). ``z`` is carried to the next level upsampled (residual init).
- The loss value is real here; CNNMRF's feval returns 0 (gradients come from the layers).
- Clamping: none inside a level (a projection between L-BFGS steps invalidates its curvature
  pairs); with ``clamp=True`` the result is clamped to [0, 1] after every level and at the
  end. CNNMRF never clamps; it min-max normalises when saving.
- Resizing: antialiased bilinear when shrinking the init, plain bilinear when upsampling
  (torch7 ``image.scale`` bilinear does neither antialiasing nor corner alignment).
"""

from __future__ import annotations

import math
import time
from typing import Callable, Protocol

import numpy as np
import torch
import torch.nn.functional as F
import torch.utils.deterministic

from ..errors import BadInputError
from ._lbfgs import LBFGS

__all__ = ["LevelLoss", "level_shapes", "optimize_image", "to_tensor", "to_image"]


class LevelLoss(Protocol):
    def __call__(self, x: torch.Tensor) -> dict[str, torch.Tensor]: ...


def to_tensor(image: np.ndarray, device: str | torch.device = "cpu") -> torch.Tensor:
    """(H, W, 3) float RGB → (1, 3, H, W) float32 tensor."""
    return torch.from_numpy(np.ascontiguousarray(image, dtype=np.float32)).permute(2, 0, 1)[None].to(device)


def to_image(x: torch.Tensor) -> np.ndarray:
    """(1, 3, H, W) tensor → (H, W, 3) float32 numpy array."""
    return x.detach()[0].permute(1, 2, 0).to("cpu", torch.float32).contiguous().numpy()


def _resize(x: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    if tuple(x.shape[-2:]) == tuple(shape):
        return x.clone()
    shrink = shape[0] < x.shape[-2] or shape[1] < x.shape[-1]
    return F.interpolate(x, size=shape, mode="bilinear", align_corners=False, antialias=shrink)


def _set_deterministic(mode: bool, warn_only: bool) -> None:
    """``torch.use_deterministic_algorithms`` for eager code. The public call also sets the
    compiler's copy of the flag, importing ``torch._inductor`` and ``torch._dynamo`` to do so
    (1.1–1.5 CPU s per process); nothing here is compiled, so unless the compiler is loaded
    already only the eager flag is set (see also _lbfgs.py)."""
    import sys

    if "torch._inductor.config" in sys.modules or not hasattr(torch._C, "_set_deterministic_algorithms"):
        torch.use_deterministic_algorithms(mode, warn_only=warn_only)
    else:
        torch._C._set_deterministic_algorithms(mode, warn_only=warn_only)


def level_shapes(shape: tuple[int, int], levels: int = 3, start_scale: float | None = None) -> list[tuple[float, tuple[int, int]]]:
    """(scale, (h, w)) per level: scale = start_scale · 2^l (default 2^-(levels-1), so the last
    level is full size); sizes ceil(size · scale) as in CNNMRF's image pyramid."""
    if levels < 1:
        raise BadInputError(f"levels must be >= 1, got {levels}")
    start = 2.0 ** -(levels - 1) if start_scale is None else float(start_scale)
    out = []
    for level in range(levels):
        s = start * 2.0**level
        out.append((s, (max(1, math.ceil(shape[0] * s)), max(1, math.ceil(shape[1] * s)))))
    return out


def optimize_image(init: np.ndarray, loss_builder: Callable[[int, float, tuple[int, int]], LevelLoss], *,
                   levels: int = 3, iters: int | tuple[int, ...] = (100, 100, 100), start_scale: float | None = None,
                   optimizer: str = "lbfgs", lbfgs_history: int = 25, line_search: str | None = "strong_wolfe",
                   lr: float | None = None, clamp: bool = True, seed: int = 0, device: str | torch.device = "cpu",
                   progress: Callable[..., None] | None = None, callback: Callable[..., None] | None = None,
                   save_every: int | None = None, level_init: str = "upsample",
                   change_mask: Callable[[tuple[int, int]], torch.Tensor] | None = None,
                   tolerance_grad: float = 1e-7, start: np.ndarray | None = None,
                   eval_budget: float = 2.0, converge: tuple[int, float] | None = None) -> tuple[np.ndarray, dict]:
    """Minimise Σ of the loss terms over the image pixels, coarse to fine (FaceTex Eq. 5).

    ``loss_builder(level, scale, (h, w))`` prepares that level's targets and returns a callable
    ``x (1, 3, h, w) -> {name: weighted scalar}``; the objective is the sum of the terms.
    ``iters`` is per level (an int is used for every level). ``optimizer`` "lbfgs" or "adam"
    (``lr`` default 1 for L-BFGS, 0.01 for Adam). ``progress(n=1, level=, loss=, terms=)`` (terms: each weighted loss term's value) is called
    once per function evaluation; ``callback(image=, level=, evaluation=)`` every
    ``save_every`` evaluations (if set) and after each level, with the (h, w, 3) image.
    ``level_init``: "upsample" starts each level from the previous result upsampled (CNNMRF);
    "residual" from the init image at the new size plus the upsampled *change* of the
    previous level, which keeps the init's fine detail (our default for transfers).
    ``change_mask(shape) -> (1, 1, h, w)`` tensor: optimise a masked change (see the module
    docstring); the level init is then always "residual". ``start``: the image the first
    level starts from (default ``init``; ``init`` stays the anchor of the residual init and
    of the masked change, so only the mask's pixels start from ``start``).
    ``converge=(k, rtol)``: a level also ends when its best loss fell by less than ``rtol``
    (relative) over its last ``k`` iterations (checked every ``k`` iterations; L-BFGS keeps its
    history across the checks); None: run the iterations (module docstring).

    Returns the final image (H, W, 3) float32 and ``info``: per-level scale, shape, seconds,
    evaluations, iterations and final value of every term; the total-loss history; settings.
    """
    init = np.asarray(init)
    if init.ndim != 3 or init.shape[2] != 3 or init.shape[0] < 1 or init.shape[1] < 1:
        raise BadInputError(f"init must be an (H, W, 3) RGB image, got shape {init.shape}")
    iters = (iters,) * levels if isinstance(iters, int) else tuple(int(i) for i in iters)
    if len(iters) != levels:
        raise BadInputError(f"iters has {len(iters)} entries for {levels} levels")
    if optimizer not in ("lbfgs", "adam"):
        raise BadInputError(f"optimizer must be 'lbfgs' or 'adam', not {optimizer!r}")
    if level_init not in ("upsample", "residual"):
        raise BadInputError(f"level_init must be 'upsample' or 'residual', not {level_init!r}")
    if line_search not in (None, "strong_wolfe"):
        raise BadInputError(f"line_search must be None or 'strong_wolfe', not {line_search!r}")
    plan = level_shapes(init.shape[:2], levels, start_scale)

    det_before = torch.are_deterministic_algorithms_enabled()
    warn_before = torch.is_deterministic_algorithms_warn_only_enabled()
    fill_before = torch.utils.deterministic.fill_uninitialized_memory
    _set_deterministic(True, warn_only=True)
    # deterministic mode also fills every new tensor with NaN (a debugging aid against reading
    # uninitialised memory; it changes no result here): 10 % of a loss evaluation's time
    torch.utils.deterministic.fill_uninitialized_memory = False
    torch.manual_seed(seed)
    info = {"optimizer": optimizer, "level_init": level_init, "line_search": line_search if optimizer == "lbfgs" else None,
            "lbfgs_history": lbfgs_history, "clamp": clamp, "seed": seed, "levels": [], "loss_history": []}
    t_all = time.perf_counter()
    try:
        source = to_tensor(init, device)
        if start is not None:
            start = np.asarray(start, np.float32)
            if start.shape != init.shape:
                raise BadInputError(f"start image has shape {start.shape}, expected {init.shape}")
        start_t = None if start is None else to_tensor(start, device)
        x_prev = None
        z_prev = None
        for level, ((scale, shape), n_iter) in enumerate(zip(plan, iters)):
            t0 = time.perf_counter()
            mask = None
            if change_mask is not None:
                mask = change_mask(tuple(shape)).to(device=source.device, dtype=source.dtype)
                base = _resize(source, shape)
                if z_prev is not None:
                    z0 = _resize(z_prev, shape)
                else:
                    z0 = torch.zeros_like(base) if start_t is None else _resize(start_t, shape) - base
                var = z0.detach().clone(memory_format=torch.contiguous_format).requires_grad_(True)
            else:
                if x_prev is None:
                    start = _resize(source if start_t is None else start_t, shape)
                elif level_init == "residual":
                    # upsample only the change made so far: the init's detail at this resolution
                    # survives instead of the previous level's blur (CNNMRF upsamples the image)
                    prev_src = _resize(source, tuple(x_prev.shape[-2:]))
                    start = _resize(source, shape) + _resize(x_prev - prev_src, shape)
                else:
                    start = _resize(x_prev, shape)
                var = start.detach().clone(memory_format=torch.contiguous_format).requires_grad_(True)
            level_loss = loss_builder(level, scale, shape)

            def image_of(v):
                return v if mask is None else base + mask * v

            evals = 0
            last = None  # (point, gradient, loss, terms) of the latest evaluation

            def closure():
                nonlocal evals, last
                if last is not None and torch.equal(var, last[0]):
                    # torch's L-BFGS evaluates its start point at every step() call: on a restart
                    # or the next convergence chunk that is the point its line search just evaluated
                    var.grad = last[1].clone()
                    return last[2]
                opt.zero_grad(set_to_none=False)
                x = image_of(var)
                terms = level_loss(x)
                total = sum(terms.values())
                total.backward()
                evals += 1
                last = (var.detach().clone(), var.grad.detach().clone(), total.detach(),
                        {k: float(v.detach()) for k, v in terms.items()})
                value = float(total.detach())
                info["loss_history"].append(value)
                if progress is not None:
                    progress(n=1, level=level, loss=value, terms=last[3])
                if callback is not None and save_every and evals % save_every == 0:
                    callback(image=to_image(x), level=level, evaluation=evals)
                return total

            iterations, restarts, stop = 0, 0, "iterations"
            if n_iter > 0:
                if optimizer == "lbfgs":
                    budget = max(1, int(round(eval_budget * n_iter)))
                    stalls, last_value = 0, None
                    first = len(info["loss_history"])
                    chunk = n_iter if converge is None else max(1, int(converge[0]))
                    # a convergence chunk also ends after eval_budget × its iterations in evaluations:
                    # line searches that take many evaluations for little decrease (the MRF loss's
                    # matches flipping at a kink) are checked like iterations
                    chunk_evals = None if converge is None else max(1, math.ceil(eval_budget * chunk))
                    best_before = None  # best loss of the level at the previous convergence check
                    opt = None
                    while iterations < n_iter:
                        ask = min(chunk, n_iter - iterations)
                        cap = max(1, budget - evals if chunk_evals is None else min(budget - evals, chunk_evals))
                        if opt is None:
                            opt = LBFGS([var], lr=1.0 if lr is None else lr, max_iter=ask, max_eval=cap,
                                        history_size=lbfgs_history, tolerance_grad=tolerance_grad,
                                        line_search_fn=line_search)
                        else:  # the next chunk of the same L-BFGS run (its history is kept)
                            opt.param_groups[0].update(max_iter=ask, max_eval=cap)
                        done_before = int(opt.state[var].get("n_iter", 0))
                        evals_before = evals
                        opt.step(closure)
                        done = int(opt.state[var].get("n_iter", 0)) - done_before
                        iterations += done
                        if iterations >= n_iter:
                            break
                        if evals >= budget:
                            stop = "evaluations"
                            break
                        ran_through = done >= ask or (chunk_evals is not None and evals - evals_before >= chunk_evals)
                        if ran_through and converge is not None:  # convergence check
                            best = min(info["loss_history"][first:])
                            if best_before is not None and best_before - best <= converge[1] * abs(best_before):
                                stop = f"converged: < {converge[1]:g} in {chunk} iterations"
                                break
                            best_before = best
                            continue
                        opt = None  # L-BFGS stopped early: restart with an empty history
                        if var.grad is not None and float(var.grad.abs().max()) <= tolerance_grad:
                            stop = "converged: gradient"
                            break
                        value = info["loss_history"][-1]
                        if last_value is not None and last_value - value <= 1e-7 * max(abs(last_value), 1e-12):
                            stalls += 1
                            if stalls >= 2:
                                stop = "converged: no decrease after restarts"
                                break
                        else:
                            stalls = 0
                        last_value = value
                        restarts += 1
                else:
                    opt = torch.optim.Adam([var], lr=1e-2 if lr is None else lr)
                    for _ in range(n_iter):
                        opt.step(closure)
                    iterations = n_iter
            with torch.no_grad():
                x = image_of(var).detach()
                if clamp:
                    x = x.clamp(0.0, 1.0)
            # Final value of every term at the level's result (one extra evaluation, unless the
            # result is the point evaluated last)
            if last is not None and torch.equal(x, image_of(last[0])):
                terms = dict(last[3])
            else:
                with torch.no_grad():
                    terms = {k: float(v.detach()) for k, v in level_loss(x).items()}
            x_prev = x
            z_prev = None if mask is None else var.detach()
            info["levels"].append({"level": level, "scale": scale, "shape": tuple(shape), "iterations": iterations,
                                   "evaluations": evals, "restarts": restarts, "stop": stop,
                                   "seconds": time.perf_counter() - t0,
                                   "loss_terms": terms, "loss": float(sum(terms.values()))})
            if callback is not None:
                callback(image=to_image(x_prev), level=level, evaluation=evals)
    finally:
        _set_deterministic(det_before, warn_only=warn_before)
        torch.utils.deterministic.fill_uninitialized_memory = fill_before
    info["seconds"] = time.perf_counter() - t_all
    return to_image(x_prev), info
