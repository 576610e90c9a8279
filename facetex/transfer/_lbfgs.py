"""L-BFGS for one tensor: ``torch.optim.LBFGS``'s algorithm without ``torch.optim.Optimizer``.

Why: every ``torch.optim.Optimizer`` imports ``torch._dynamo`` (and with it ``torch._inductor``)
on its first use — ``add_param_group`` and ``zero_grad`` are wrapped in
``torch._compile._disable_dynamo`` — which costs 1.1–1.5 CPU seconds per process, a quarter of a
``--preset preview`` transfer. Nothing here is compiled.

The iteration is ``torch.optim.lbfgs.LBFGS.step`` (torch 2.x, BSD-3-Clause licence, itself a
port of torch7 ``optim.lbfgs``) line by line, for a single parameter tensor; the strong-Wolfe
line search is torch's own ``_strong_wolfe``. The iterates are bitwise those of
``torch.optim.LBFGS`` (tests/transfer/test_optimize.py checks it).
"""

from __future__ import annotations

import torch
from torch.optim.lbfgs import _strong_wolfe

__all__ = ["LBFGS"]


def _value(loss) -> float:
    return float(loss.detach()) if torch.is_tensor(loss) else float(loss)


class LBFGS:
    """``torch.optim.LBFGS(params=[param], ...)`` for one tensor. ``state[param]`` holds the
    counters (``n_iter``, ``func_evals``) and history; ``param_groups[0]`` the settings
    (``max_iter``/``max_eval`` may be changed between ``step`` calls)."""

    def __init__(self, params, lr: float = 1.0, max_iter: int = 20, max_eval: int | None = None,
                 tolerance_grad: float = 1e-7, tolerance_change: float = 1e-9, history_size: int = 100,
                 line_search_fn: str | None = None):
        params = list(params)
        if len(params) != 1:
            raise ValueError("this L-BFGS optimises exactly one tensor")
        if not 0.0 <= lr:
            raise ValueError(f"Invalid learning rate: {lr}")
        if line_search_fn not in (None, "strong_wolfe"):
            raise ValueError("only 'strong_wolfe' is supported")
        self.param = params[0]
        self.param_groups = [{"params": params, "lr": lr, "max_iter": max_iter,
                              "max_eval": max_iter * 5 // 4 if max_eval is None else max_eval,
                              "tolerance_grad": tolerance_grad, "tolerance_change": tolerance_change,
                              "history_size": history_size, "line_search_fn": line_search_fn}]
        self.state = {self.param: {}}

    def zero_grad(self, set_to_none: bool = True) -> None:
        p = self.param
        if p.grad is None:
            return
        if set_to_none:
            p.grad = None
        else:
            if p.grad.grad_fn is not None:
                p.grad.detach_()
            else:
                p.grad.requires_grad_(False)
            p.grad.zero_()

    def _gather_flat_grad(self) -> torch.Tensor:
        p = self.param
        if p.grad is None:
            return p.new(p.numel()).zero_()
        return torch.cat([p.grad.view(-1)], 0)  # a copy, as torch's (the closure zeroes the gradient in place)

    def _add_grad(self, step_size, update) -> None:
        self.param.add_(update.view_as(self.param), alpha=step_size)

    def _directional_evaluate(self, closure, x, t, d):
        self._add_grad(t, d)
        loss = _value(closure())
        flat_grad = self._gather_flat_grad()
        self.param.copy_(x)
        return loss, flat_grad

    @torch.no_grad()
    def step(self, closure):
        """One ``torch.optim.LBFGS.step``: up to ``max_iter`` iterations / ``max_eval``
        evaluations of ``closure`` (which must compute the loss and its gradient)."""
        closure = torch.enable_grad()(closure)
        group = self.param_groups[0]
        lr, max_iter, max_eval = group["lr"], group["max_iter"], group["max_eval"]
        tolerance_grad, tolerance_change = group["tolerance_grad"], group["tolerance_change"]
        line_search_fn, history_size = group["line_search_fn"], group["history_size"]

        state = self.state[self.param]
        state.setdefault("func_evals", 0)
        state.setdefault("n_iter", 0)

        orig_loss = closure()
        loss = _value(orig_loss)
        current_evals = 1
        state["func_evals"] += 1

        flat_grad = self._gather_flat_grad()
        opt_cond = flat_grad.abs().max() <= tolerance_grad
        if opt_cond:
            return orig_loss

        d, t = state.get("d"), state.get("t")
        old_dirs, old_stps, ro = state.get("old_dirs"), state.get("old_stps"), state.get("ro")
        H_diag = state.get("H_diag")
        prev_flat_grad, prev_loss = state.get("prev_flat_grad"), state.get("prev_loss")

        n_iter = 0
        while n_iter < max_iter:
            n_iter += 1
            state["n_iter"] += 1

            # descent direction
            if state["n_iter"] == 1:
                d = flat_grad.neg()
                old_dirs, old_stps, ro = [], [], []
                H_diag = 1
            else:
                y = flat_grad.sub(prev_flat_grad)
                s = d.mul(t)
                ys = y.dot(s)
                if ys > 1e-10:
                    if len(old_dirs) == history_size:
                        old_dirs.pop(0)
                        old_stps.pop(0)
                        ro.pop(0)
                    old_dirs.append(y)
                    old_stps.append(s)
                    ro.append(1.0 / ys)
                    H_diag = ys / y.dot(y)
                num_old = len(old_dirs)
                if "al" not in state:
                    state["al"] = [None] * history_size
                al = state["al"]
                q = flat_grad.neg()
                for i in range(num_old - 1, -1, -1):
                    al[i] = old_stps[i].dot(q) * ro[i]
                    q.add_(old_dirs[i], alpha=-al[i])
                d = r = torch.mul(q, H_diag)
                for i in range(num_old):
                    be_i = old_dirs[i].dot(r) * ro[i]
                    r.add_(old_stps[i], alpha=al[i] - be_i)

            if prev_flat_grad is None:
                prev_flat_grad = flat_grad.clone(memory_format=torch.contiguous_format)
            else:
                prev_flat_grad.copy_(flat_grad)
            prev_loss = loss

            # step length
            if state["n_iter"] == 1:
                t = min(1.0, 1.0 / flat_grad.abs().sum()) * lr
            else:
                t = lr
            gtd = flat_grad.dot(d)
            if gtd > -tolerance_change:
                break

            ls_func_evals = 0
            if line_search_fn is not None:
                x_init = self.param.clone(memory_format=torch.contiguous_format)

                def obj_func(x, t, d):
                    return self._directional_evaluate(closure, x, t, d)

                loss, flat_grad, t, ls_func_evals = _strong_wolfe(obj_func, x_init, t, d, loss, flat_grad, gtd,
                                                                  max_ls=max_eval - current_evals)
                self._add_grad(t, d)
                opt_cond = flat_grad.abs().max() <= tolerance_grad
            else:
                self._add_grad(t, d)
                if n_iter != max_iter:
                    with torch.enable_grad():
                        loss = _value(closure())
                    flat_grad = self._gather_flat_grad()
                    opt_cond = flat_grad.abs().max() <= tolerance_grad
                    ls_func_evals = 1

            current_evals += ls_func_evals
            state["func_evals"] += ls_func_evals

            # stop conditions
            if n_iter == max_iter:
                break
            if current_evals >= max_eval:
                break
            if opt_cond:
                break
            if d.mul(t).abs().max() <= tolerance_change:
                break
            if abs(loss - prev_loss) < tolerance_change:
                break

        state.update(d=d, t=t, old_dirs=old_dirs, old_stps=old_stps, ro=ro, H_diag=H_diag,
                     prev_flat_grad=prev_flat_grad, prev_loss=prev_loss)
        return orig_loss
