"""A batch of independent height-field networks ``z = f(u, v)``, one per (chart, fold) copy.

Every copy has the same architecture and its own weights; all copies are evaluated with one
batched matrix product, so fitting many charts costs one forward pass, not a Python loop.

Architectures
-------------
``"ridge"``
    One hidden layer of ridge units ``s(a u + b v + c)`` with the logistic sigmoid ``s``, summed
    with output weights: the network of the source method (Chen & Jain's "nonlinear cascade of
    affine transformations" with one hidden layer).
``"mlp"``
    ``depth`` hidden layers of ``tanh`` units (our choice for the default: deeper networks fit
    creases and steps with fewer units).

Inputs and outputs are in the chart's normalised coordinates (about [-1, 1]); the caller scales.
"""

from __future__ import annotations

import math
import platform
from pathlib import Path

import torch

from scanrig.errors import InputError

ARCHITECTURES = ("ridge", "mlp")


def _tanh_is_slow() -> bool:
    """Whether torch's float32 ``tanh`` is slower here than ``2 σ(2 z) − 1``.

    torch built with MKL takes ``tanh`` from MKL's vector math, and on a CPU not made by Intel
    that is a slow path: on a 2-core AMD EPYC (torch 2.13, one thread, 20 blocks of 24 × 2073
    activations) ``tanh`` took 5.5 ms and ``sigmoid`` 1.3 ms (0.6 ms more for ``2 s − 1``), so
    that a hidden layer's forward and backward passes took 0.66 times as long in the logistic
    form, and the 100 000-point filter 0.92 times the wall time. MKL's fast path is Intel's:
    an earlier measurement of these layers, on a machine whose processor was not recorded, found
    torch's ``tanh`` three times faster than ``2 σ(2 z) − 1``; without MKL torch vectorises
    ``tanh`` as it does ``sigmoid``.
    """
    if not torch.backends.mkl.is_available():
        return False
    try:
        vendor = Path("/proc/cpuinfo").read_text(errors="replace")
    except OSError:  # not Linux: the processor's name, which names its vendor on Windows
        vendor = platform.processor()
    return "AuthenticAMD" in vendor or "HygonGenuine" in vendor


#: tanh units are evaluated as ``2 σ(2 z) − 1`` (within 2e-7 of ``tanh``; see :func:`_tanh_is_slow`).
LOGISTIC_TANH = _tanh_is_slow()


class HeightFieldNets(torch.nn.Module):
    """``n_models`` independent networks mapping ``(u, v)`` to ``z``.

    Parameters
    ----------
    n_models : int
        Number of independent copies.
    hidden : int
        Units per hidden layer.
    depth : int
        Hidden layers (``"ridge"`` requires 1).
    architecture : {"ridge", "mlp"}
        See the module docstring.
    generator : torch.Generator
        Seeds the initial weights.
    first_layer_scale : float
        Standard deviation of the first-layer weights; larger values start with sharper ridges.
    """

    def __init__(self, n_models: int, *, hidden: int, depth: int, architecture: str,
                 generator: torch.Generator, first_layer_scale: float = 3.0):
        super().__init__()
        if architecture not in ARCHITECTURES:
            raise InputError(f"architecture must be one of {ARCHITECTURES}, got {architecture!r}")
        if architecture == "ridge" and depth != 1:
            raise InputError(f"the 'ridge' network has one hidden layer, got depth={depth}")
        if hidden < 1 or depth < 1:
            raise InputError(f"hidden and depth must be >= 1, got {hidden}, {depth}")
        self.architecture = architecture
        self.tanh_units = architecture == "mlp"  # else logistic units
        #: ``tanh z`` evaluated as ``2 σ(2 z) − 1``, the doubling in the layer's small operand
        self.logistic_tanh = self.tanh_units and LOGISTIC_TANH
        widths = [2] + [hidden] * depth + [1]
        weights, biases = [], []
        for i, (w_in, w_out) in enumerate(zip(widths[:-1], widths[1:])):
            std = first_layer_scale if i == 0 else 1.0 / math.sqrt(w_in)
            weights.append(torch.nn.Parameter(
                std * torch.randn(n_models, w_in, w_out, generator=generator)))
            bias_std = first_layer_scale if i == 0 else 0.0
            biases.append(torch.nn.Parameter(
                bias_std * torch.randn(n_models, 1, w_out, generator=generator)))
        self.weights = torch.nn.ParameterList(weights)
        self.biases = torch.nn.ParameterList(biases)

    @classmethod
    def concatenate(cls, parts: list[HeightFieldNets], order: torch.Tensor) -> HeightFieldNets:
        """One batch holding the copies of several batches of the same architecture.

        Parameters
        ----------
        parts : list of HeightFieldNets
            Same ``architecture``, ``hidden`` and ``depth``.
        order : (n_models,) int tensor
            Copy ``i`` of the result is copy ``order[i]`` of the parts' copies laid end to end.
        """
        first = parts[0]
        out = cls(1, hidden=first.weights[0].shape[-1], depth=len(first.weights) - 1,
                  architecture=first.architecture, generator=torch.Generator())
        with torch.no_grad():
            for mine, theirs in ((out.weights, [p.weights for p in parts]),
                                 (out.biases, [p.biases for p in parts])):
                for i in range(len(mine)):
                    mine[i] = torch.nn.Parameter(torch.cat([t[i] for t in theirs])[order])
        return out

    def subset(self, copies: torch.Tensor) -> HeightFieldNets:
        """The copies ``copies`` (int tensor) as a batch of their own, with copied weights."""
        return HeightFieldNets.concatenate([self], copies)

    @torch.no_grad()
    def assign(self, copies: torch.Tensor, part: HeightFieldNets) -> None:
        """Set the copies ``copies`` (int tensor) to the copies of ``part``, in order."""
        for mine, theirs in ((self.weights, part.weights), (self.biases, part.biases)):
            for p, q in zip(mine, theirs):
                p[copies] = q

    def features(self, uv: torch.Tensor, copies: torch.Tensor | None = None) -> torch.Tensor:
        """Activations of the last hidden layer, unit-major.

        The points lie along the last, contiguous axis: the products of every layer and their
        gradients then run over long contiguous rows, and the normal equations of the output
        layer need no transposed copy (an epoch took 3-20 % less time than point-major
        activations, torch 2.13 on 2 CPU cores, measured).

        Parameters
        ----------
        uv : (n_models, n, 2) tensor, or (V, n, 2) with ``copies``
            Normalised chart coordinates.
        copies : (V,) int tensor, optional
            Which copy's weights evaluate each batch entry (several entries may share a copy:
            its points split in blocks of equal size); default: entry i is copy i.

        Returns
        -------
        (n_models or V, hidden, n) tensor
            The output layer is affine in these: ``z = w_out . features + b_out``.
        """
        h = uv.transpose(1, 2)
        for w, b in self._hidden_layers(copies):
            w, b = self._layer_operands(w, b)
            h = self._activate(torch.baddbmm(b.transpose(1, 2), w.transpose(1, 2), h), keep_sigmoid=True)
        return h

    @torch.no_grad()
    def training_activations(self, uv: torch.Tensor, copies: torch.Tensor | None = None) -> list[torch.Tensor]:
        """The input and every hidden layer's activations, each with a row of ones, for :meth:`backward`.

        The same values as :meth:`features` (to rounding), without a graph. Each layer's bias
        is its weights' last row against the row of ones, so a layer is one product (the
        broadcast bias of ``baddbmm`` costs a copy and a second pass over the layer) and the
        biases' gradients come with the weights' in :meth:`backward`. The second layer of 20
        blocks of 2073 points took 1.19 ms instead of 1.30 (one thread, medians, measured).

        Parameters
        ----------
        uv, copies
            As in :meth:`features`.

        Returns
        -------
        list of ``depth + 1`` tensors
            ``(V, 3, n)`` (``u``, ``v``, 1), then ``(V, hidden + 1, n)`` per hidden layer; the
            features are ``layers[-1][:, :-1]``.
        """
        n_entries, n, _ = uv.shape
        layers = [torch.cat([uv.transpose(1, 2), uv.new_ones(n_entries, 1, n)], dim=1)]
        for w, b in self._hidden_layers(copies):
            out = uv.new_empty(n_entries, w.shape[2] + 1, n)
            out[:, -1] = 1.0
            hidden = out[:, :-1]
            torch.bmm(torch.cat(self._layer_operands(w, b), dim=1).transpose(1, 2), layers[-1], out=hidden)
            self._activate(hidden, keep_sigmoid=False)
            layers.append(out)
        return layers

    @torch.no_grad()
    def backward(self, layers: list[torch.Tensor], grad_output: torch.Tensor,
                 copies: torch.Tensor | None = None) -> None:
        """Set the hidden layers' ``.grad`` to the gradient of a loss, the output layer held fixed.

        Written out instead of autograd because the output layer is solved, not descended, and
        the network is a few small layers whose passes over the activations are the cost: the
        output weights are taken out of the last layer's gradient (they scale the small
        operands of its products instead of forming an outer product with the points), and
        the biases' gradients come with the weights' from the rows of ones. 20 blocks of 2073
        points: 4.4 ms against autograd's 5.0 (one thread, medians, measured).

        Parameters
        ----------
        layers : list of tensors
            :meth:`training_activations` of the same ``uv`` and ``copies``.
        grad_output : (n_models or V, n) tensor
            Gradient of the loss with respect to each output height.
        copies : (V,) int tensor, optional
            As in :meth:`features`; the blocks' gradients are summed per copy.
        """
        hidden = self._hidden_layers(copies)
        w_out = (self.weights[-1] if copies is None else self.weights[-1][copies])[..., 0]  # (V, hidden)
        # d loss / d (pre-activation) of the last layer is w_out[i] * act'[i, l] * grad_output[l]:
        # its act' * grad_output here, w_out applied to the products below
        grad = grad_output[:, None, :].expand(-1, w_out.shape[1], -1)
        scale = w_out
        for i in range(len(hidden) - 1, -1, -1):
            w, _ = hidden[i]
            grad_pre = self._activation_backward(grad, layers[i + 1][:, :-1])
            # [dW^T | db] of this layer: (V, out, in + 1)
            grad_params = torch.bmm(grad_pre, layers[i].transpose(1, 2))
            if scale is not None:
                grad_params.mul_(scale[:, :, None])
            if i > 0:
                grad = torch.bmm(w if scale is None else w * scale[:, None, :], grad_pre)
            scale = None
            self._store_grad(self.weights[i], grad_params[:, :, :-1].transpose(1, 2), copies)
            self._store_grad(self.biases[i], grad_params[:, None, :, -1], copies)

    def _hidden_layers(self, copies: torch.Tensor | None) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Weights ``(V, in, out)`` and biases ``(V, 1, out)`` of every hidden layer, per batch
        entry (a slice of a ParameterList builds a new module at every call)."""
        layers = list(zip(self.weights, self.biases))[:-1]
        return layers if copies is None else [(w[copies], b[copies]) for w, b in layers]

    def _layer_operands(self, w: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A hidden layer's weights and biases as its units take them: doubled for ``2 σ(2 z) − 1``."""
        return (2.0 * w, 2.0 * b) if self.logistic_tanh else (w, b)

    def _activate(self, pre: torch.Tensor, *, keep_sigmoid: bool) -> torch.Tensor:
        """The units' outputs from their pre-activations (as :meth:`_layer_operands` takes them),
        in place; with ``keep_sigmoid`` the last step of ``2 σ − 1`` goes into a new tensor, as
        autograd needs the sigmoid's output for its backward."""
        if not self.tanh_units:
            return pre.sigmoid_()
        if not self.logistic_tanh:
            return pre.tanh_()
        s = pre.sigmoid_()
        return (s.mul(2.0) if keep_sigmoid else s.mul_(2.0)).sub_(1.0)

    def _activation_backward(self, grad: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
        """Gradient before the activation from the one after it and the activation's output: the
        fused kernels autograd uses for ``tanh`` and ``sigmoid``."""
        if self.tanh_units:
            return torch.ops.aten.tanh_backward(grad, out)
        return torch.ops.aten.sigmoid_backward(grad, out)

    @staticmethod
    def _store_grad(param: torch.Tensor, grad: torch.Tensor, copies: torch.Tensor | None) -> None:
        """``param.grad`` from per-entry gradients, summed over the entries of each copy."""
        if copies is not None:
            grad = torch.zeros_like(param).index_add_(0, copies, grad)
        param.grad = grad.contiguous()

    def hidden_parameters(self) -> list[torch.nn.Parameter]:
        """Weights and biases of the hidden layers (the output layer is solved, not descended)."""
        return list(self.weights[:-1]) + list(self.biases[:-1])

    @torch.no_grad()
    def set_output(self, coef: torch.Tensor) -> None:
        """Set the linear output layer from ``(n_models, hidden + 1)`` coefficients (last = bias)."""
        self.weights[-1].copy_(coef[:, :-1, None])
        self.biases[-1].copy_(coef[:, None, -1:])

    def forward(self, uv: torch.Tensor) -> torch.Tensor:
        """Heights of every copy at its own inputs.

        Parameters
        ----------
        uv : (n_models, n, 2) tensor
            As in :meth:`features`.

        Returns
        -------
        (n_models, n) tensor
            Normalised heights.
        """
        h = self.features(uv)
        return torch.baddbmm(self.biases[-1], self.weights[-1].transpose(1, 2), h)[:, 0]
