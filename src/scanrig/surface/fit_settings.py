"""Network, loss and training schedule of the robust fit (:class:`FitSettings`).

The schedule these settings drive is described in :mod:`scanrig.surface.robust_fit`; each
attribute's docstring gives the measurement behind its default.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from scanrig.errors import InputError
from scanrig.surface.hampel import HampelConstants, check_q

LOSSES = ("hampel", "mse", "huber")
HUBER_K = 1.345  # Huber's cut-off in units of sigma: 95 % Gaussian efficiency


@dataclass(frozen=True)
class FitSettings:
    """Network, loss and training schedule of the robust fit.

    Attributes
    ----------
    q : float
        Tolerated fraction of bad data in (0, 0.5]: breakdown point of the noise scale (of the
        start and of every update).
    loss : {"hampel", "mse", "huber"}
        ``"hampel"`` is the robust method; ``"mse"`` and ``"huber"`` are the baselines (same
        network, ``epochs`` epochs, no robust start and no reweighting step).
    architecture, hidden, depth : str, int, int
        Network, see :class:`~scanrig.surface.network.HeightFieldNets`.
    n_folds : int
        Folds for the held-out residuals (>= 2).
    start_neighbours : int
        Neighbours of the local trimmed planes of the robust start (``"hampel"`` only, see
        :mod:`scanrig.surface.local_start`).
    start_epochs : int
        Epochs of least squares on the start's good points, the others replaced by the chart's
        quadratic through them (:func:`~scanrig.surface.local_start.fill_with_quadratic`), before
        the Hampel loss.
    robust_epochs : int
        Full-batch epochs of back-propagation on the Hampel loss (``"hampel"``). 160: with the
        reweighting step after them, 200 gave the same accuracy (mean over the 24 protocol
        cells and three weight seeds 1.0375 times the oracle both) in 8 % more time; 120 was
        worse (1.0414, plane at 40 % 1.29).
    warmup_epochs : int
        Epochs over which the Hampel phase's Adam step rises linearly to ``learning_rate``
        (``"hampel"``; 0 = none). A fresh Adam moves every weight by the full step from the
        first epoch, whatever its gradient, and threw a started fit out of its basin (saddle
        at 10 %, weight seed 5: from 0.6 sigma to 4 sigma in 30 epochs, final 2.3 times the
        oracle; 1.05 times with 50 warm-up epochs, 20 were not enough).
    update_every : int
        Epochs between updates of the noise scale and the cut-offs.
    final_irls : int
        Iteratively reweighted least-squares steps of the output layer after the last epoch.
    epochs : int
        Full-batch epochs of least-squares training: the baselines' whole training (``"mse"``;
        ``"huber"`` on its loss).
    refit : bool
        Reweighting step (``"hampel"`` only): the final robust weights frozen, the networks
        trained on from the Hampel phase's hidden layers by weighted least squares.
    refit_epochs, refit_step, refit_warmup_epochs : int, float, int
        Schedule of the reweighting step: its epochs, its Adam step as a fraction of
        ``learning_rate`` and the epochs of its linear warm-up. Trained on from the Hampel
        phase instead of retrained from the initial weights for ``epochs`` (200) at the full
        step, it needs fewer epochs: the 100 000-point scan 1.25x less CPU (the 64 x 64
        protocol cells at 10 and 20 %, two data draws: mean ratio to the oracle 0.957 and
        0.997 instead of 1.006 and 1.017, worst 1.093 instead of 1.116). At the full step
        (200 epochs, 20 warm-up) the sphere and the crease went to 1.13-1.19.
    learning_rate : float
        Adam step at the start; it decays by cosine to ``learning_rate / 20``.
    constants : HampelConstants
        ``(p, r, gamma)`` of the tanh estimator.
    scale_cut : float
        Truncation, in units of the scale, of the refinement steps of the noise scale
        (:func:`~scanrig.surface.hampel.robust_scale`); below the rejection point ``r`` so that
        one-sided outliers just beyond ``r`` sigma cannot inflate it.
    n_boot : int
        Bootstrap resamples for the upper bound of the noise scale.
    alpha : float
        One-sided level of that bound.
    mixture_neighbours : int
        Neighbours (in the chart plane) of the local mixture that weighs each point by its
        posterior probability of being an inlier before the reweighting step and in the last
        output-layer steps (:mod:`scanrig.surface.mixture`; ``"hampel"`` with ``refit`` only;
        0 = off). It takes out part of the one-sided outliers inside the noise band: over the
        24 protocol cells and weight seeds 0-5, crease at 20 % 1.155 -> 1.100 times the oracle
        (worst seed 1.201 -> 1.150), at 40 % 1.193 -> 1.126 (1.315 -> 1.200), mean of all cells
        1.016 -> 1.007 (seeds 0-2) and 1.010 -> 1.005 (3-5). On the crease at 20 and 40 %
        (seeds 0-1, residuals then scaled by the cut-off), 50 or 200 neighbours were within
        0.04 of 100.
    mixture_window : float
        The outliers' density per unit residual is counted over ``(r, mixture_window * r]``
        noise scales (> 1); 1.25 was within 0.01 of 1.5 on the crease as above.
    converge_every : int
        Epochs between convergence checks of the weighted least-squares phases (``"hampel"``:
        the start and the reweighting step; 0 = none): a network whose loss fell by less than
        ``converge_tol`` of itself since the last check stops there and leaves the batch
        (``_Active``). The cosine schedule keeps lowering every loss a little to its end; most
        networks stop after half of it or less. The Hampel phase is checked alike, see
        ``robust_converge_checks``.
    converge_tol : float
        Relative fall of the loss below which a network counts as converged.
    robust_converge_checks : int
        Checks in a row that a network's Hampel loss must pass to stop in the Hampel phase
        (``"hampel"``; 0 = that phase is not checked). One was not enough: its cut-offs shrink
        and its weights settle over the first epochs, and a loss that paused there stopped the
        saddle (32 x 32, 20 % outliers, seed 0) at 1.15 times the oracle instead of 1.00
        (``converge_tol`` 0.001: 1.15 as well); with two, 1.00.
    train_points : int
        Most points each network's hidden layers train on (0 = all): a copy with more is given a
        subsample spread over its chart's area (:func:`~scanrig.surface.subsample.stratified_subsample`),
        while the output layer's last steps, the reweighting step's weights, the noise scale and
        the scores use every point. Off by default: the default network's effective degrees of
        freedom on a plane are ~150-200 (0.37 sigma from 1024 points, 0.56-0.59 from 600), so
        points beyond a few thousand still lower its error. On the 100 000-point scan (seeds
        0-2) 2000 took 1.2-1.4x less CPU, denoised inliers 0.266 and 0.275 sigma instead of
        0.263 and 0.267 and recall 0.916 and 0.940 instead of 0.946 and 0.938 (seeds 0 and 2).
    """

    q: float = 0.25
    loss: str = "hampel"
    architecture: str = "mlp"
    hidden: int = 24
    depth: int = 2
    n_folds: int = 2
    start_neighbours: int = 24
    start_epochs: int = 60
    robust_epochs: int = 160
    warmup_epochs: int = 50
    update_every: int = 40
    final_irls: int = 5
    epochs: int = 200
    refit: bool = True
    refit_epochs: int = 100
    refit_step: float = 0.3
    refit_warmup_epochs: int = 20
    learning_rate: float = 0.01
    constants: HampelConstants = field(default_factory=HampelConstants)
    scale_cut: float = 2.5
    n_boot: int = 200
    alpha: float = 0.05
    mixture_neighbours: int = 100
    mixture_window: float = 1.5
    converge_every: int = 20
    converge_tol: float = 3e-3
    robust_converge_checks: int = 2
    train_points: int = 0

    def __post_init__(self):
        check_q(self.q)
        if self.loss not in LOSSES:
            raise InputError(f"loss must be one of {LOSSES}, got {self.loss!r}")
        if self.n_folds < 2:
            raise InputError(f"n_folds must be >= 2, got {self.n_folds}")
        if min(self.epochs, self.robust_epochs, self.update_every, self.final_irls) < 1:
            raise InputError("epochs, robust_epochs, update_every and final_irls must be >= 1")
        if min(self.refit_epochs, self.refit_warmup_epochs) < 0 or not self.refit_step > 0:
            raise InputError(f"refit_epochs and refit_warmup_epochs must be >= 0 and refit_step > 0, got "
                             f"{self.refit_epochs}, {self.refit_warmup_epochs}, {self.refit_step}")
        if min(self.start_epochs, self.warmup_epochs, self.mixture_neighbours) < 0:
            raise InputError(f"start_epochs, warmup_epochs and mixture_neighbours must be >= 0, got "
                             f"{self.start_epochs}, {self.warmup_epochs}, {self.mixture_neighbours}")
        if self.train_points < 0:
            raise InputError(f"train_points must be >= 0, got {self.train_points}")
        if min(self.converge_every, self.robust_converge_checks) < 0:
            raise InputError(f"converge_every and robust_converge_checks must be >= 0, got "
                             f"{self.converge_every}, {self.robust_converge_checks}")
        if not self.mixture_window > 1.0:
            raise InputError(f"mixture_window must be > 1, got {self.mixture_window}")
