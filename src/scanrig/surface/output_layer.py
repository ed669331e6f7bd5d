"""The networks' linear output layer: its weighted least-squares solve and its evaluation.

The output layer of every height-field network is not descended but solved, for the current
hidden layers, from the weighted normal equations of its copy's blocks (variable projection,
:mod:`scanrig.surface.robust_fit`).
"""

from __future__ import annotations

import torch

def weighted_solve(feats: torch.Tensor, t: torch.Tensor, root_weight: torch.Tensor, owner: torch.Tensor,
                    n_copies: int) -> torch.Tensor:
    """Weighted least-squares output layer of every copy: (M, H + 1) float64 (last = bias), no gradient.

    Solves ``(F^T W F + lambda I) c = F^T W t`` for the features ``F`` with a constant column,
    summing the normal equations of each copy's blocks, with a tiny ridge ``lambda`` relative
    to the trace for copies whose features are nearly collinear. The normal equations are
    formed in float32 from the features and heights less their weighted means over the copy
    (:func:`centred_rows`), then solved in float64 and the bias moved back: 0.6 of the time of
    float64 normal equations (20 blocks of 2073 points, one thread, measured). Centred,
    because a trained network's units are nearly constant over a chart and float32 rounds
    relative to the uncentred products: at the features of networks trained by least squares
    on clean 64 x 64 surfaces (sphere, saddle, scan, plane, two seeds each), uncentred float32
    moved the fit by up to 0.074 sigma from float64's; centred, with 20 % zero weights, by at
    most 0.012 sigma (0.026 at the edge of a step), and the fits' errors stayed those of
    float64 to 0.013 sigma.

    Parameters
    ----------
    feats : (V, H, L) tensor
        Unit-major features of each block (:meth:`HeightFieldNets.features`).
    t : (V, L) tensor
        Target heights.
    root_weight : (V, L) float64 tensor
        Square roots of the weights (taken by the caller: in a phase of fixed weights, once;
        they were 8 % of the filter's time under cProfile when taken every epoch).
    owner : (V,) int tensor
        Copy of each block.
    n_copies : int
    """
    size = feats.shape[1]
    rows, mean_f, mean_t = centred_rows(feats.detach(), t, root_weight.float(), owner, n_copies)
    # one product gives the normal matrix and the right-hand side: [F 1 t]^T W [F 1 t], with the
    # points along the contiguous axis (a third faster than F^T (W F) plus F^T (W t))
    normal = torch.zeros(n_copies, size + 2, size + 2, dtype=torch.float64, device=feats.device).index_add_(
        0, owner, (rows @ rows.transpose(1, 2)).double())
    gram, rhs = normal[:, :size + 1, :size + 1], normal[:, :size + 1, size + 1]
    diagonal = gram.diagonal(dim1=1, dim2=2)
    # the ridge relative to the trace of the uncentred normal matrix, as if formed uncentred
    # (the centred trace is far smaller, and its ridge let collinear units take large coefficients)
    trace = diagonal.sum(dim=1) + gram[:, size, size] * mean_f.double().square().sum(dim=1)
    diagonal.add_(1e-9 * trace[:, None].clamp(min=1e-12))
    # the ridge makes every system positive definite: Cholesky, 1.5x faster than LU on these
    # 25 x 25 systems; LU only for the copies where rounding defeats it (copies with fewer points
    # than units, e.g. the fold networks of the 30-60-point pieces of reflection blobs)
    factor, info = torch.linalg.cholesky_ex(gram)
    coef = torch.cholesky_solve(rhs[..., None], factor)[..., 0]
    failed = torch.nonzero(info)[:, 0]
    if len(failed):
        coef[failed] = torch.linalg.solve(gram[failed], rhs[failed])
    # c . (f - mean_f) + c0 = c . f + (c0 - c . mean_f), fitted to t - mean_t
    coef[:, size] += mean_t.double() - (coef[:, :size] * mean_f.double()).sum(dim=1)
    return coef


def centred_rows(feats: torch.Tensor, t: torch.Tensor, root_weight: torch.Tensor, owner: torch.Tensor,
                  n_copies: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``W^(1/2) [F - mean_f, 1, t - mean_t]`` per block, float32, and the copies' weighted means.

    Parameters
    ----------
    feats : (V, H, L) float32 tensor
    t : (V, L) float32 tensor
    root_weight : (V, L) float32 tensor
    owner : (V,) int tensor
    n_copies : int

    Returns
    -------
    rows : (V, H + 2, L) float32 tensor
    mean_f : (M, H) float32 tensor
        Weighted mean of each copy's features (float32: the solve is exact for any centre;
        the nearer the mean, the smaller the rounding of the normal equations).
    mean_t : (M,) float32 tensor
    """
    n_blocks, size, n = feats.shape
    weight = root_weight.square()

    def per_copy_mean(block_sums: torch.Tensor, total: torch.Tensor) -> torch.Tensor:
        sums = torch.zeros((n_copies, *block_sums.shape[1:]), dtype=block_sums.dtype, device=block_sums.device)
        return sums.index_add_(0, owner, block_sums) / total.reshape(-1, *[1] * (block_sums.dim() - 1))

    total = torch.zeros(n_copies, dtype=weight.dtype, device=weight.device).index_add_(
        0, owner, weight.sum(dim=1)).clamp(min=1e-30)  # a copy of zero weights: any centre
    mean_f = per_copy_mean(torch.bmm(feats, weight[:, :, None])[..., 0], total)
    mean_t = per_copy_mean((t * weight).sum(dim=1), total)
    rows = torch.empty(n_blocks, size + 2, n, dtype=feats.dtype, device=feats.device)
    torch.sub(feats, mean_f[owner][:, :, None], out=rows[:, :size]).mul_(root_weight[:, None, :])
    rows[:, size].copy_(root_weight)
    torch.sub(t, mean_t[owner][:, None], out=rows[:, size + 1]).mul_(root_weight)
    return rows, mean_f, mean_t


def output_heights(feats: torch.Tensor, coef: torch.Tensor) -> torch.Tensor:
    """Output layer per block: features (V, H, L), coefficients (V, H + 1) -> heights (V, L) float32.

    A batched matrix-vector product: with its backward, half the time of a broadcast product
    and sum over the units, which forms a (V, H, L) temporary (measured, torch 2.13 on CPU,
    one thread, 36 blocks of 2798 points).
    """
    coef = coef.float()
    return torch.baddbmm(coef[:, -1:, None], coef[:, None, :-1], feats)[:, 0]
