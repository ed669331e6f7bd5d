"""Adam on a few small parameter tensors, with the step schedule of a training phase.

The arithmetic is that of ``torch.optim.Adam`` (default betas and eps, no weight decay) on its
single-tensor CPU path, operation for operation, with the step ``lr * factor(step)`` that a
``LambdaLR`` schedule would give: the parameters come out identical to the bit (``test_adam``).
Written out because the networks' hidden layers are a handful of tensors of a few thousand
numbers, and on those ``torch.optim.Adam`` with ``LambdaLR`` spent more time in its per-step
wrappers and in a lazy import of ``torch._dynamo`` (1.8 s at the first optimiser) than in
arithmetic: 4.6 s of the 100 000-point filter's 60 s under cProfile, of which 1.4 s were the
update itself (torch 2.13, 2 CPU cores, measured).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch

BETA1, BETA2, EPS = 0.9, 0.999, 1e-8


class Adam:
    """Adam (Kingma & Ba 2015) with the learning rate ``lr * factor(t)`` at step ``t = 0, 1, ...``.

    Parameters
    ----------
    params : sequence of torch.Tensor
        Leaf tensors with ``requires_grad``; updated in place from their ``.grad``.
    lr : float
        Base learning rate.
    factor : callable int -> float
        Multiplier of ``lr`` at each step.
    """

    def __init__(self, params: Sequence[torch.Tensor], lr: float, factor: Callable[[int], float]):
        self.params = list(params)
        self.lr = lr
        self.factor = factor
        self.steps = 0
        self._mean = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        self._square = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]

    def select(self, params: Sequence[torch.Tensor], rows: torch.Tensor) -> Adam:
        """This optimiser on ``params``, which hold the rows ``rows`` (int tensor, first axis) of
        its own parameters: same schedule and step count, the moments of those rows."""
        out = Adam(params, self.lr, self.factor)
        out.steps = self.steps
        out._mean = [m[rows] for m in self._mean]
        out._square = [v[rows] for v in self._square]
        return out

    def lr_at(self, step: int) -> float:
        """The learning rate of step ``step`` (0 = the first)."""
        return self.lr * self.factor(step)

    def zero_grad(self) -> None:
        """Drop the parameters' gradients (``set_to_none``)."""
        for p in self.params:
            p.grad = None

    @torch.no_grad()
    def step(self) -> None:
        """One Adam step from the current gradients."""
        lr = self.lr_at(self.steps)
        self.steps += 1
        step_size = lr / (1 - BETA1 ** float(self.steps))
        correction2_sqrt = (1 - BETA2 ** float(self.steps)) ** 0.5
        for p, mean, square in zip(self.params, self._mean, self._square):
            grad = p.grad
            mean.lerp_(grad, 1 - BETA1)
            square.mul_(BETA2).addcmul_(grad, grad, value=1 - BETA2)
            p.addcdiv_(mean, (square.sqrt() / correction2_sqrt).add_(EPS), value=-step_size)
