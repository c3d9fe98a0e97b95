"""studio.imitate.adam: the search's Adam equals torch.optim.Adam bit for bit on the CPU, and a search never
imports torch._dynamo (which torch's optimisers import on their first step: 1.5 s of every process)."""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from studio.imitate.adam import Adam


@pytest.mark.parametrize("lr", [0.05, 0.3])
def test_steps_equal_torchs_adam_bit_for_bit(lr):
    """The same parameter, the same loss and the same gradients, 60 steps: every step's parameters identical."""
    g = torch.Generator().manual_seed(3)
    start = torch.randn(16, 21, generator=g)
    target = torch.randn(16, 21, generator=g)
    ours, theirs = start.clone().requires_grad_(True), start.clone().requires_grad_(True)
    mine, reference = Adam(ours, lr=lr), torch.optim.Adam([theirs], lr=lr)
    for step in range(60):
        for p, opt in ((ours, mine), (theirs, reference)):
            opt.zero_grad(set_to_none=True) if opt is reference else opt.zero_grad()
            (torch.sin(3 * p) * target + (p - target) ** 2).sum().backward()
            opt.step()
        assert torch.equal(ours, theirs), f"step {step}: {float((ours - theirs).abs().max())}"
    assert mine.steps == 60 and ours.grad is not None


def test_a_step_without_a_gradient_changes_nothing():
    p = torch.ones(3, requires_grad=True)
    opt = Adam(p, lr=0.1)
    opt.step()
    assert torch.equal(p, torch.ones(3)) and opt.steps == 0


@pytest.mark.slow
def test_a_search_in_a_fresh_process_never_imports_torch_dynamo():
    """The gradient search of the shipped self-model, a few steps, in a process of its own: torch._dynamo stays
    unloaded (torch.optim.Adam's first step loads it). The still imitation's module is imported too (what every
    imitation verb loads)."""
    code = (
        "import sys\n"
        "import numpy as np\n"
        "from studio.imitate.config import LossConfig, SearchConfig\n"
        "from studio.imitate.losses import ImageLoss\n"
        "from studio.imitate.search import gradient_search\n"
        "from studio.learn.selfmodel import load_selfmodel\n"
        "from studio.imitate.still import DEFAULT_MODEL\n"
        "model, _ = load_selfmodel(DEFAULT_MODEL, device='cpu')\n"
        "r = model.cfg.resolution\n"
        "target = np.zeros((r, r), np.uint8); target[r // 4 : 3 * r // 4, r // 3 : 2 * r // 3] = 1\n"
        "loss = ImageLoss(target, LossConfig(use_clip=False, crop_size=r))\n"
        "out = gradient_search(model, loss, SearchConfig(batch=4, iterations=5))\n"
        "print(np.isfinite(out.loss), out.iterations, 'torch._dynamo' in sys.modules)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.split()[-3:] == ["True", "5", "False"], done.stdout
