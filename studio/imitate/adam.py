"""Adam on one tensor without ``torch.optim``: the gradient search's optimiser.

torch's optimisers wrap their steps in ``torch._disable_dynamo``, whose first call imports ``torch._dynamo``: 1.5 s of
every process that searches (each imitation verb, each worker of a spread run, the notebook's first search) for a
handful of tensor operations. :class:`Adam` is ``torch.optim.Adam``'s single-tensor step at its defaults
(β = (0.9, 0.999), ε = 1e-8, no weight decay, no AMSGrad): the same operations in the same order, so on the CPU its
steps equal torch's bit for bit (``tests/test_adam.py`` holds them to it). Training keeps ``torch.optim.AdamW``
(one long process, where the import is nothing).
"""

from __future__ import annotations

import torch

__all__ = ["Adam"]


class Adam:
    """Adam over the one tensor ``param`` (a leaf that requires grad), stepped after each ``backward()``."""

    def __init__(self, param: torch.Tensor, lr: float, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8):
        self.param = param
        self.lr, self.betas, self.eps = float(lr), betas, float(eps)
        self.steps = 0  # steps taken
        self.exp_avg = torch.zeros_like(param, memory_format=torch.preserve_format)  # the gradient's running mean
        self.exp_avg_sq = torch.zeros_like(param, memory_format=torch.preserve_format)  # … and its square's

    def zero_grad(self) -> None:
        """Forget the gradient (as ``set_to_none=True``)."""
        self.param.grad = None

    @torch.no_grad()
    def step(self) -> None:
        """One Adam step from ``param.grad`` (nothing when there is none)."""
        grad = self.param.grad
        if grad is None:
            return
        beta1, beta2 = self.betas
        self.steps += 1
        step = float(self.steps)
        self.exp_avg.lerp_(grad, 1 - beta1)
        self.exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
        bias_correction1 = 1 - beta1**step
        bias_correction2_sqrt = (1 - beta2**step) ** 0.5
        denom = (self.exp_avg_sq.sqrt() / bias_correction2_sqrt).add_(self.eps)
        self.param.addcdiv_(self.exp_avg, denom, value=-(self.lr / bias_correction1))
