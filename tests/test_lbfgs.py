"""avatarkit.lbfgs.LBFGS against its reference, torch.optim.LBFGS: the same points evaluated, bit
for bit, on problems that exercise the line search's bracket and zoom phases, a full history
(the oldest pair dropped), several parameter tensors and steps that carry state over."""
import sys

import numpy as np
import pytest
import torch

from avatarkit.lbfgs import LBFGS


def _rosenbrock(params):
    x, y = params
    return (1 - x).pow(2).sum() + 100 * (y - x.pow(2)).pow(2).sum()


def _least_squares(params):
    a, b = params
    gen = torch.Generator().manual_seed(3)
    m = torch.randn(40, 9, generator=gen, dtype=torch.float64)
    target = torch.randn(40, generator=gen, dtype=torch.float64)
    z = torch.cat([a.reshape(-1), b.reshape(-1)])
    # a soft-min term makes it non-quadratic, as the fits' silhouette terms are
    return ((m @ z - target) ** 2).mean() + 0.1 * torch.logsumexp(-z / 0.05, 0) * 0.05 + (z ** 4).sum() * 1e-2


def _start(problem):
    if problem is _rosenbrock:
        return [torch.tensor([-1.2, 0.3], dtype=torch.float64), torch.tensor([1.0, -0.5], dtype=torch.float64)]
    return [torch.linspace(-1, 1, 6, dtype=torch.float64).reshape(2, 3), torch.tensor([0.5, -2.0, 3.0], dtype=torch.float64)]


def _run(cls, problem, steps, **kwargs):
    params = [p.clone().requires_grad_(True) for p in _start(problem)]
    opt = cls(params, **kwargs)
    seen = []

    def closure():
        opt.zero_grad()
        seen.append(torch.cat([p.detach().reshape(-1).clone() for p in params]))
        loss = problem(params)
        loss.backward()
        return loss

    losses = [opt.step(closure).detach().clone() for _ in range(steps)]
    return [p.detach().clone() for p in params], seen, losses, dict(opt.state[params[0]] if cls is torch.optim.LBFGS
                                                                   else opt.state)


@pytest.mark.parametrize("problem", [_rosenbrock, _least_squares])
@pytest.mark.parametrize("kwargs", [
    dict(lr=1.0, max_iter=60, line_search_fn="strong_wolfe", tolerance_grad=1e-10, tolerance_change=1e-12,
         history_size=20),
    dict(lr=1.0, max_iter=25, line_search_fn="strong_wolfe", tolerance_grad=1e-12, tolerance_change=1e-14,
         history_size=3),
    dict(lr=0.5, max_iter=15, history_size=5),  # fixed steps, no line search
])
def test_lbfgs_is_torch_lbfgs_bit_for_bit(problem, kwargs):
    ours = _run(LBFGS, problem, 3, **kwargs)
    ref = _run(torch.optim.LBFGS, problem, 3, **kwargs)
    assert len(ours[1]) == len(ref[1]) > 10
    for a, b in zip(ours[1], ref[1]):
        assert torch.equal(a, b)
    for a, b in zip(ours[0] + ours[2], ref[0] + ref[2]):
        assert torch.equal(a, b)
    assert ours[3]["n_iter"] == ref[3]["n_iter"] and ours[3]["func_evals"] == ref[3]["func_evals"]
    if kwargs.get("history_size") == 3 and problem is _least_squares:
        assert len(ours[3]["old_dirs"]) == 3  # the history filled and dropped pairs


def test_lbfgs_solves_rosenbrock():
    params, _, _, _ = _run(LBFGS, _rosenbrock, 2, lr=1.0, max_iter=100, line_search_fn="strong_wolfe",
                           tolerance_grad=1e-12, tolerance_change=1e-14)
    assert np.allclose(torch.cat(params).numpy(), 1.0, atol=1e-6)


def test_lbfgs_rejects_what_it_does_not_copy():
    x = torch.zeros(2, dtype=torch.float64, requires_grad=True)
    with pytest.raises(ValueError):
        LBFGS([x], line_search_fn="backtracking")
    with pytest.raises(ValueError):
        LBFGS([torch.zeros(2, dtype=torch.complex128, requires_grad=True)])
    with pytest.raises(ValueError):
        LBFGS([])


def test_lbfgs_does_not_import_torch_dynamo():
    """The point of the copy: a fit never pays for the torch._dynamo import torch.optim's
    optimizers make (import torch itself loads torch.optim, but not torch._dynamo)."""
    import subprocess

    code = ("import sys, torch\n"
            "from avatarkit.lbfgs import LBFGS\n"
            "x = torch.tensor([3.0], dtype=torch.float64, requires_grad=True)\n"
            "opt = LBFGS([x], line_search_fn='strong_wolfe')\n"
            "def c():\n    opt.zero_grad(); l = (x - 1).pow(2).sum(); l.backward(); return l\n"
            "opt.step(c)\n"
            "print(sorted(m for m in sys.modules if m.startswith('torch._dynamo')))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
