"""scanrig's Adam against torch.optim.Adam with a LambdaLR schedule: the same parameters to the bit."""

import math

import torch

from scanrig.surface.adam import Adam


def _trajectory(make_optimizer, steps=60):
    gen = torch.Generator().manual_seed(3)
    params = [torch.randn(5, 2, 7, generator=gen).requires_grad_(),
              torch.randn(5, 1, 7, generator=gen).requires_grad_()]
    target = torch.randn(5, 7, 9, generator=gen)
    x = torch.randn(5, 9, 2, generator=gen)
    step = make_optimizer(params)
    for _ in range(steps):
        # a loss with curvature, so that the moments and the bias corrections matter
        loss = ((torch.tanh(x @ params[0] + params[1]) - target.transpose(1, 2)) ** 2).sum()
        loss.backward()
        step(params)
    return [p.detach() for p in params]


def _factor(epoch):
    return (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(epoch, 60) / 60))) * min(1.0, (epoch + 1) / 7)


def test_adam_is_torch_adam_with_lambda_lr_to_the_bit():
    def ours(params):
        opt = Adam(params, 0.01, _factor)

        def step(_):
            opt.step()
            opt.zero_grad()
        return step

    def torchs(params):
        opt = torch.optim.Adam(params, lr=0.01)
        sched = torch.optim.lr_scheduler.LambdaLR(opt, _factor)

        def step(_):
            opt.step()
            sched.step()
            opt.zero_grad(set_to_none=True)
        return step

    for mine, reference in zip(_trajectory(ours), _trajectory(torchs)):
        assert torch.equal(mine, reference)


def test_adam_steps_then_forgets_the_gradients():
    p = torch.zeros(3, requires_grad=True)
    opt = Adam([p], 0.1, lambda t: 1.0)
    p.grad = torch.tensor([1.0, -2.0, 0.0])
    opt.step()
    # the first step of Adam moves each coordinate by lr against the sign of its gradient
    torch.testing.assert_close(p.detach(), torch.tensor([-0.1, 0.1, 0.0]), atol=1e-6, rtol=0)
    opt.zero_grad()
    assert p.grad is None and opt.steps == 1


def test_adam_on_a_selection_of_rows_steps_as_on_the_whole():
    gen = torch.Generator().manual_seed(4)
    whole = torch.randn(5, 3, generator=gen).requires_grad_()
    opt = Adam([whole], 0.01, lambda t: 1.0 / (1 + t))
    grads = torch.randn(6, 5, 3, generator=gen)
    for g in grads[:3]:
        whole.grad = g.clone()
        opt.step()
    rows = torch.tensor([0, 3])
    part = whole.detach()[rows].clone().requires_grad_()
    part_opt = opt.select([part], rows)
    for g in grads[3:]:
        whole.grad, part.grad = g.clone(), g[rows].clone()
        opt.step()
        part_opt.step()
    assert part_opt.steps == opt.steps and torch.equal(part.detach(), whole.detach()[rows])
