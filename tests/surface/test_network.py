"""Batched height-field networks, and charts of different sizes fitted in groups."""

import dataclasses
import itertools
import platform
import subprocess
import sys

import numpy as np
import pytest
import torch
from hypothesis import given, settings as hypothesis_settings, strategies as st

from scanrig.errors import InputError
from scanrig.surface.network import HeightFieldNets
from scanrig.surface.hampel import hampel_weight
from scanrig.surface.chart_batches import _size_batches, fit_charts_by_size
from scanrig.surface.fit_settings import FitSettings
from scanrig.surface.output_layer import weighted_solve
from scanrig.surface.robust_fit import (_Active, _adam, _Blocks, _bounded_by_heldout, _heldout_prediction,
                                      _irls_weight, _output_layer_irls, _robust_loss, _weighted_least_squares,
                                      concatenate_fits, fit_charts)

from .conftest import SIGMA, tilted_plane_with_outliers


@pytest.mark.parametrize("architecture, depth", [("ridge", 1), ("mlp", 2)])
def test_copies_are_independent_and_output_layer_is_linear_in_features(architecture, depth):
    gen = torch.Generator().manual_seed(0)
    nets = HeightFieldNets(3, hidden=5, depth=depth, architecture=architecture, generator=gen)
    uv = torch.rand(3, 7, 2, generator=gen)
    z = nets(uv)
    assert z.shape == (3, 7)
    coef = torch.randn(3, 6, generator=gen)
    nets.set_output(coef)
    expected = (nets.features(uv) * coef[:, :-1, None]).sum(dim=1) + coef[:, -1:]
    torch.testing.assert_close(nets(uv), expected)
    # changing copy 0's input does not change copies 1 and 2
    uv2 = uv.clone()
    uv2[0] += 1.0
    torch.testing.assert_close(nets(uv2)[1:], nets(uv)[1:])


@pytest.mark.parametrize("architecture, depth, logistic_tanh",
                         [("ridge", 1, False), ("mlp", 2, False), ("mlp", 3, False), ("mlp", 2, True), ("mlp", 3, True)])
def test_hand_written_backward_is_autograds_gradient(architecture, depth, logistic_tanh):
    # blocks 0 and 2 share copy 1, copy 2 has none: its gradient must be zero
    gen = torch.Generator().manual_seed(4)
    nets = HeightFieldNets(3, hidden=6, depth=depth, architecture=architecture, generator=gen)
    nets.logistic_tanh = logistic_tanh  # both forms of tanh, whichever this CPU runs faster
    nets.set_output(torch.randn(3, 7, generator=gen))
    uv = torch.rand(3, 11, 2, generator=gen, dtype=torch.float32) * 2 - 1
    copies = torch.tensor([1, 0, 1])
    grad_output = torch.randn(3, 11, generator=gen)
    out = torch.baddbmm(nets.biases[-1][copies], nets.weights[-1][copies].transpose(1, 2),
                        nets.features(uv, copies))[:, 0]
    expected = torch.autograd.grad((out * grad_output).sum(), nets.hidden_parameters())
    layers = nets.training_activations(uv, copies)
    torch.testing.assert_close(layers[-1][:, :-1], nets.features(uv, copies).detach())
    nets.backward(layers, grad_output, copies)
    for param, reference in zip(nets.hidden_parameters(), expected):
        torch.testing.assert_close(param.grad, reference, rtol=1e-5, atol=1e-6)
        assert torch.all(param.grad[2] == 0) and torch.any(param.grad[:2] != 0)


def test_both_forms_of_tanh_give_the_same_network():
    # tanh z and 2 sigmoid(2 z) - 1 agree to float32 rounding, in the values, their training
    # activations and their gradients
    gen = torch.Generator().manual_seed(6)
    nets = HeightFieldNets(4, hidden=24, depth=2, architecture="mlp", generator=gen)
    nets.set_output(torch.randn(4, 25, generator=gen))
    uv = torch.rand(4, 500, 2, generator=gen) * 2 - 1
    grad_output = torch.randn(4, 500, generator=gen)
    outputs = {}
    for logistic in (False, True):
        nets.logistic_tanh = logistic
        layers = nets.training_activations(uv)
        nets.backward(layers, grad_output)
        outputs[logistic] = (nets(uv).detach(), layers[-1], [p.grad.clone() for p in nets.hidden_parameters()])
    (z0, act0, grad0), (z1, act1, grad1) = outputs[False], outputs[True]
    assert (act1 - act0).abs().max() < 1e-6
    torch.testing.assert_close(z1, z0, rtol=0, atol=1e-5)
    for g0, g1 in zip(grad0, grad1):
        torch.testing.assert_close(g1, g0, rtol=1e-4, atol=1e-4 * g0.abs().max().item())


@pytest.mark.parametrize("loss", ["mse", "huber", "hampel"])
def test_irls_weight_times_residual_is_the_derivative_of_the_loss(loss):
    # the training loops take the loss's gradient as w(r) r
    gen = torch.Generator().manual_seed(5)
    r = (torch.randn(2, 200, generator=gen, dtype=torch.float64) * 3).requires_grad_(True)
    m = torch.rand(2, 200, generator=gen) > 0.2
    cut = {"a": torch.tensor([[1.0], [0.5]], dtype=torch.float64), "b": torch.tensor([[2.5], [1.2]], dtype=torch.float64),
           "huber": torch.tensor([[1.3], [0.7]], dtype=torch.float64)}
    cut["beta"] = 0.915 / (cut["b"] / 4)
    (expected,) = torch.autograd.grad(_robust_loss(r, m, loss, cut).sum(), r)
    torch.testing.assert_close(_irls_weight(r.detach(), m, loss, cut) * r.detach(), expected)


def test_ridge_network_has_one_hidden_layer():
    with pytest.raises(InputError, match="one hidden layer"):
        HeightFieldNets(1, hidden=4, depth=2, architecture="ridge", generator=torch.Generator())
    with pytest.raises(InputError, match="architecture"):
        HeightFieldNets(1, hidden=4, depth=1, architecture="siren", generator=torch.Generator())


def test_charts_of_different_sizes_are_fitted_in_groups_and_returned_in_input_order():
    # three planes of different sizes and offsets: each chart's fit must follow its own data
    rng = np.random.default_rng(5)
    sizes, offsets = [40, 400, 90], [2.0, -1.0, 0.5]
    uv = [rng.uniform(-1, 1, (n, 2)) for n in sizes]
    z = [o + 0.3 * p[:, 0] + rng.normal(0, 0.01, len(p)) for o, p in zip(offsets, uv)]
    settings = FitSettings(hidden=6, depth=1, epochs=60, robust_epochs=60, refit_epochs=60, update_every=30,
                           start_epochs=20, n_boot=50)
    fits = fit_charts_by_size(uv, z, settings=settings, rng=np.random.default_rng(0), overhead_points=10)
    padded = np.zeros((3, max(sizes), 2))
    for c, p in enumerate(uv):
        padded[c, :len(p)] = p
    predicted = fits.predict(padded)
    for c, n in enumerate(sizes):
        assert np.sqrt(np.mean((fits.z_fit[c, :n] - z[c]) ** 2)) < 0.05
        np.testing.assert_allclose(predicted[c, :n], fits.z_fit[c, :n], atol=1e-5)
    assert fits.sigma.shape == (3,) and all(h["sigma_upper"].shape == (3,) for h in fits.history)


def test_joined_fits_end_with_every_parts_final_state_when_one_stopped_early():
    # a batch whose networks all converge early has fewer scale updates than the others; the
    # joined history must still end with each chart's final state (the trust test reads it)
    rng = np.random.default_rng(3)
    uv = rng.uniform(-1, 1, (2, 60, 2))
    z = 0.2 * uv[..., 0] + rng.normal(0, 0.01, (2, 60))
    settings = FitSettings(hidden=6, depth=1, robust_epochs=60, refit_epochs=20, update_every=20, start_epochs=10,
                           n_boot=20)
    full = fit_charts(uv, z, np.ones((2, 60), bool), settings=settings, rng=np.random.default_rng(0))
    early = dataclasses.replace(full, history=[full.history[0], full.history[-1]])
    assert len(full.history) == 4
    joined = concatenate_fits([full, early], np.array([0, 3, 1, 2]))
    final = np.concatenate([full.history[-1]["rejected"], early.history[-1]["rejected"]])[[0, 3, 1, 2]]
    np.testing.assert_array_equal(joined.history[-1]["rejected"], final)
    assert [h["epoch"] for h in joined.history] == [0, 60]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noise_scale_is_measured_on_the_network_as_trained(seed):
    # a clean plane: every update of the noise scale must see about the noise. The hidden layers
    # move at every step; measured with the output layer solved for the previous step's hidden
    # layers, the scale at epoch 40 was 1.66 and 1.37 times the noise on seeds 1 and 2 (nearly
    # collinear features with large output weights amplify the step).
    points, _, _, _ = tilted_plane_with_outliers(np.random.default_rng(seed), n_side=64, eps=0.0)
    fits = fit_charts_by_size([points[:, :2]], [points[:, 2]], settings=FitSettings(),
                              rng=np.random.default_rng(seed))
    upper = np.array([h["sigma_upper"][0] for h in fits.history])
    # the bootstrap bound's own spread at 4096 points is a few per cent
    assert upper.max() < 1.15 * SIGMA, upper / SIGMA


def _step_sizes(opt, epochs):
    """The learning rate of each of ``epochs`` steps of ``opt`` (scanrig's Adam, no gradients needed)."""
    return np.array([opt.lr_at(t) for t in range(epochs)])


def test_adam_schedule_is_torch_cosine_decay_times_a_linear_warm_up():
    nets = HeightFieldNets(1, hidden=3, depth=1, architecture="mlp", generator=torch.Generator().manual_seed(0))
    settings = FitSettings(learning_rate=0.01)
    plain = _step_sizes(_adam(nets, settings, 100), 100)
    reference_opt = torch.optim.Adam(nets.hidden_parameters(), lr=0.01)
    reference_sched = torch.optim.lr_scheduler.CosineAnnealingLR(reference_opt, T_max=100, eta_min=0.01 / 20)
    reference = []
    for _ in range(100):
        reference.append(reference_opt.param_groups[0]["lr"])
        reference_opt.step()
        reference_sched.step()
    np.testing.assert_allclose(plain, reference, rtol=1e-12)
    warm = _step_sizes(_adam(nets, settings, 100, warmup_epochs=10), 100)
    np.testing.assert_allclose(warm[:10] / plain[:10], np.arange(1, 11) / 10, rtol=1e-12)
    np.testing.assert_array_equal(warm[10:], plain[10:])


def test_negative_warm_up_is_rejected():
    with pytest.raises(InputError, match="start_epochs, warmup_epochs and mixture_neighbours must be >= 0, "
                                         "got 60, -1, 100"):
        FitSettings(warmup_epochs=-1)


def test_reweighting_schedule_is_checked():
    with pytest.raises(InputError, match="refit_epochs and refit_warmup_epochs must be >= 0 and refit_step > 0, "
                                         "got 100, 20, 0.0"):
        FitSettings(refit_step=0.0)
    with pytest.raises(InputError, match="got -1, 20, 0.3"):
        FitSettings(refit_epochs=-1)


def test_learning_rate_overrides_the_settings_step():
    nets = HeightFieldNets(1, hidden=4, depth=1, architecture="mlp", generator=torch.Generator().manual_seed(0))
    settings = FitSettings()
    full = _step_sizes(_adam(nets, settings, 100), 100)
    smaller = _step_sizes(_adam(nets, settings, 100, learning_rate=0.3 * settings.learning_rate), 100)
    np.testing.assert_allclose(smaller, 0.3 * full, rtol=1e-12)


def _batch_cost(batches, sizes, overhead):
    return sum(overhead + sizes[b].max() * len(b) for b in batches)


@hypothesis_settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(1, 5000), min_size=1, max_size=7), st.sampled_from([0.0, 10.0, 2500.0]))
def test_size_batches_partition_the_charts_at_least_cost(size_list, overhead):
    sizes = np.array(size_list)
    batches = _size_batches(sizes, overhead)
    assert sorted(np.concatenate(batches).tolist()) == list(range(len(sizes)))
    # against every cut of the sorted sizes into contiguous batches
    order = np.argsort(-sizes, kind="stable")
    best = min(_batch_cost(np.split(order, list(cuts)), sizes, overhead)
               for r in range(len(sizes)) for cuts in itertools.combinations(range(1, len(sizes)), r))
    assert _batch_cost(batches, sizes, overhead) == pytest.approx(best)


def test_weighted_solve_matches_numpy_least_squares():
    gen = torch.Generator().manual_seed(3)
    feats = torch.rand(4, 5, 50, generator=gen)  # copy c's points in blocks 2c and 2c + 1
    t = torch.randn(4, 50, generator=gen)
    weight = torch.rand(4, 50, generator=gen, dtype=torch.float64)
    coef = weighted_solve(feats, t, weight.sqrt(), torch.tensor([0, 0, 1, 1]), 2).numpy()
    for c in range(2):
        f = feats[2 * c: 2 * c + 2].transpose(1, 2).reshape(-1, 5).double().numpy()
        f = np.column_stack([f, np.ones(len(f))])  # the bias
        w = np.sqrt(weight[2 * c: 2 * c + 2].reshape(-1).numpy())
        expected = np.linalg.lstsq(f * w[:, None], t[2 * c: 2 * c + 2].reshape(-1).double().numpy() * w, rcond=None)[0]
        np.testing.assert_allclose(coef[c], expected, rtol=1e-6, atol=1e-8)


# a round of temporaries of 0.1-10 MB allocated and freed in turn, as in a training epoch; the
# script prints the minor page faults of the second round
_TEMPORARIES_SCRIPT = """
import resource, sys
import numpy as np
from scanrig.surface.memory import keep_freed_memory
if sys.argv[1] == "tuned":
    assert keep_freed_memory() is True and keep_freed_memory() is True
def round_of_temporaries():
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for n_bytes in (1 << 20, 6 << 20, 3 << 20, 40 << 20, 2 << 20):
        a = np.ones(n_bytes // 8)
        b = np.ones(n_bytes // 4)
        del a
        c = np.ones(n_bytes // 16)
        del b, c
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
round_of_temporaries()
print(round_of_temporaries())
"""


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt tuning is glibc's")
def test_freed_memory_is_reused_without_page_faults():
    # malloc's settings are the whole process's and page faults are counted for all its threads, so
    # each case runs in a fresh process: inside the test runner's worker, whatever earlier tests left
    # behind (heap layout, threads) counted too. With glibc's defaults the second round page-faults
    # about 1,900-2,400 times here (memory returned and mapped afresh); tuned, none.
    def second_round_faults(case):
        run = subprocess.run([sys.executable, "-c", _TEMPORARIES_SCRIPT, case], capture_output=True, text=True,
                             timeout=120, check=True)
        return int(run.stdout)

    assert second_round_faults("defaults") > 256
    assert second_round_faults("tuned") < 64


def _random_copies(seed, n_charts=2, n=30):
    """Random networks of ``n_charts`` charts x (full + 2 fold networks), their blocks, random weights
    in [0, 1] and fixed cut-offs."""
    k = 3  # copies per chart: the full network and its 2 fold networks
    gen = torch.Generator().manual_seed(seed)
    nets = HeightFieldNets(n_charts * k, hidden=5, depth=2, architecture="mlp", generator=gen)
    rng = np.random.default_rng(seed)
    uv = torch.as_tensor(rng.uniform(-1, 1, (n_charts, n, 2)), dtype=torch.float32)
    z = torch.as_tensor(rng.normal(0, 1, (n_charts, n)), dtype=torch.float32)
    fold = rng.integers(0, 2, (n_charts, n))
    x = uv[:, None].expand(-1, k, -1, -1).reshape(-1, n, 2)
    t = z[:, None].expand(-1, k, -1).reshape(-1, n)
    mask = np.stack([np.ones((n_charts, n), bool)] + [fold != j for j in range(2)], axis=1).reshape(-1, n)
    rows = _Blocks.of(x, t, mask, n_folds=2)
    weight = torch.as_tensor(rng.uniform(0, 1, tuple(rows.m.shape))) * rows.m
    cut = {"a": torch.full((n_charts * k, 1), 0.5), "b": torch.full((n_charts * k, 1), 1.5),
           "beta": torch.full((n_charts * k, 1), 2.0)}
    return nets, rows, weight, cut, x, t, z, fold


def test_full_network_weights_are_bounded_by_the_held_out_ones():
    # each full-network weight must become min(own, Hampel weight of z minus the fold network
    # that did not see the point)
    nets, rows, weight, cut, x, t, z, fold = _random_copies(4)
    n_charts, k, n = fold.shape[0], 3, fold.shape[1]
    z_chart, heldout = _heldout_prediction(nets, x, t, fold)
    bounded = _bounded_by_heldout(rows, weight, z_chart - heldout, FitSettings(), {"torch": cut}).numpy()
    with torch.no_grad():
        pred = nets(x).reshape(n_charts, k, n).numpy()
    for v in range(len(rows.owner)):
        copy = int(rows.owner[v])
        chart, member = divmod(copy, k)
        for slot in np.flatnonzero(rows.m[v].numpy()):
            point = int(rows.index[v, slot])
            if member == 0:
                r = float(z[chart, point]) - pred[chart, 1 + fold[chart, point], point]
                expected = min(float(weight[v, slot]), float(hampel_weight(np.array(r), 0.5, 1.5, 2.0)))
            else:
                expected = float(weight[v, slot])
            assert bounded[v, slot] == pytest.approx(expected, abs=1e-6)


def test_monotone_output_layer_irls_never_raises_a_weight_and_leaves_the_optimum():
    nets, rows, weight, cut, *_ = _random_copies(7)
    settings = FitSettings(final_irls=3)
    free = _output_layer_irls(nets, rows, weight, settings, {"torch": cut})
    assert (free > weight + 1e-6).any()  # the plain steps do raise weights here
    capped = _output_layer_irls(nets, rows, weight, settings, {"torch": cut}, monotone=True)
    assert torch.all(capped <= weight)
    with torch.no_grad():
        feats = nets.features(rows.x, rows.owner)
        optimum = weighted_solve(feats, rows.t, capped.sqrt(), rows.owner, rows.n_copies).float()
    torch.testing.assert_close(nets.weights[-1][:, :, 0], optimum[:, :-1], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(nets.biases[-1][:, 0, 0], optimum[:, -1], rtol=1e-5, atol=1e-6)


def test_converged_copies_stop_where_they_were_at_the_check():
    # a tolerance no loss can meet freezes every copy at the first comparison (epoch 10): they
    # must hold the hidden layers of 10 steps of the full schedule and their output layer's
    # optimum for them, as the plain loop leaves them
    nets, rows, weight, *_ = _random_copies(5)
    every, epochs = 10, 100
    frozen = HeightFieldNets.concatenate([nets], torch.arange(rows.n_copies))
    stopped = _weighted_least_squares(frozen, rows, weight, FitSettings(converge_every=every, converge_tol=1e9),
                                      epochs)
    assert stopped.tolist() == [every] * rows.n_copies
    opt = _adam(nets, FitSettings(), epochs)
    for _ in range(every):
        r, layers = rows.residual(nets, weight)
        rows.backward(nets, layers, weight.float() * r / rows.n_train[:, None])
        opt.step()
    rows.residual(nets, weight)
    for mine, reference in zip(frozen.parameters(), nets.parameters()):
        assert torch.equal(mine, reference)
    never = HeightFieldNets.concatenate([frozen], torch.arange(rows.n_copies))
    stopped = _weighted_least_squares(never, rows, weight, FitSettings(converge_every=every, converge_tol=-1e9), epochs)
    assert stopped.tolist() == [epochs] * rows.n_copies


def test_a_copy_stops_only_after_the_required_checks_in_a_row():
    # losses per copy at the checks (every 10 epochs): copy 0 flat, falling, flat, flat; copy 1
    # falling, flat, flat; the others always falling. With two checks in a row, copy 1 stops at
    # epoch 30 and copy 0, whose first pass was broken, at 40; with one check, both at 10 and 20.
    nets, rows, *_ = _random_copies(8)
    falling = [8.0, 4.0, 2.0, 1.0, 0.5]
    losses = {0: [1.0, 1.0, 0.5, 0.5, 0.5], 1: [1.0, 0.5, 0.5, 0.5, 0.5]}
    blocks_per_copy = torch.bincount(rows.owner, minlength=rows.n_copies).double()
    for checks, expected in ((2, {0: 40, 1: 30}), (1, {0: 10, 1: 20})):
        settings = FitSettings(converge_every=10)
        active = _Active(nets, rows, _adam(nets, settings, 100), settings, checks=checks)
        for i in range(5):
            per_copy = torch.tensor([losses.get(c, falling)[i] for c in range(rows.n_copies)], dtype=torch.float64)
            left = per_copy[active.copies] / blocks_per_copy[active.copies]  # spread over each copy's blocks
            active.check(10 * i, left[active.rows.owner])
        assert {c: int(active.stopped[c]) for c in (0, 1)} == expected
        assert (active.stopped[2:] == -1).all()


def test_negative_convergence_checks_are_rejected():
    with pytest.raises(InputError, match=r"^converge_every and robust_converge_checks must be >= 0, got 20, -1$"):
        FitSettings(robust_converge_checks=-1)


def test_a_subset_of_copies_is_written_back_alone_and_its_blocks_cut_alike():
    nets, rows, *_ = _random_copies(6)
    before = [p.detach().clone() for p in nets.parameters()]
    copies = torch.tensor([1, 4])
    part = nets.subset(copies)
    with torch.no_grad():
        for p in part.parameters():
            p.add_(1.0)
    nets.assign(copies, part)
    others = torch.tensor([0, 2, 3, 5])
    for p, p0 in zip(nets.parameters(), before):
        torch.testing.assert_close(p[copies], p0[copies] + 1.0)
        assert torch.equal(p[others], p0[others])
    own_rows, blocks = rows.select(copies)
    assert own_rows.n_copies == 2 and set(own_rows.owner.tolist()) == {0, 1}
    assert torch.equal(own_rows.x, rows.x[blocks]) and torch.equal(rows.owner[blocks] == 4, own_rows.owner == 1)


def test_a_copy_keeps_its_cholesky_solution_when_another_copy_of_the_batch_needs_lu(monkeypatch):
    # copy 1 of the first batch has 3 points for 25 unknowns: its normal matrix is singular but
    # for the tiny ridge, which the float32 rounding of its products defeats (Cholesky fails and
    # LU solves it); copy 0 keeps, bit for bit, the solution it has beside a well-posed copy
    gen = torch.Generator().manual_seed(7)
    feats = torch.rand(3, 24, 50, generator=gen)
    t = torch.randn(3, 50, generator=gen)
    weight = torch.ones(3, 50, dtype=torch.float64)
    feats[1, :, 3:], weight[1, 3:] = 0.0, 0.0
    owner = torch.tensor([0, 1])
    lu_systems = []
    lu = torch.linalg.solve
    monkeypatch.setattr(torch.linalg, "solve", lambda a, b: lu_systems.append(len(a)) or lu(a, b))
    beside_singular = weighted_solve(feats[:2], t[:2], weight[:2].sqrt(), owner, 2)
    assert lu_systems == [1]  # copy 1 alone went to LU
    beside_posed = weighted_solve(feats[[0, 2]], t[[0, 2]], weight[[0, 2]].sqrt(), owner, 2)
    assert torch.equal(beside_singular[0], beside_posed[0])
    alone = weighted_solve(feats[1:2], t[1:2], weight[1:2].sqrt(), torch.tensor([0]), 1)[0]
    assert torch.isfinite(beside_singular[1]).all()
    torch.testing.assert_close(beside_singular[1], alone)
