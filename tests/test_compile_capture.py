"""What the emulated GPU cannot see, checked on the CPU: ``torch.compile`` runs eagerly under the
emulation, so a compiled step that recompiles when a CUDA graph capture begins (where compiling
would read the CUDA RNG state, which a capture forbids), or that hands out outputs a later step
overwrites (CUDA graph trees, ``compile.mode=reduce-overhead``), is checked here."""

from __future__ import annotations

from types import SimpleNamespace

import torch

from gcnt.nn.baselines.smp import SMPDown, SMPUp
from gcnt.recipes import CompileConfig
from gcnt.rl.td3.learner import delayed_update, loss_rows


def test_smp_compiled_passes_do_not_recompile_when_a_capture_begins(monkeypatch):
    """dynamo traces SMP's message passes as on a CUDA device (``is_cuda``), and the capture
    flag flips between two calls, as CudaGraphModule's warm-up and capture calls see it: a
    compiled pass that read the flag would have guarded on it and recompiles, an error here."""
    import torch._dynamo
    from torch._dynamo.variables.base import VariableTracker
    from torch._dynamo.variables.tensor import TensorVariable

    monkeypatch.setattr(
        TensorVariable, "method_attr_is_cuda", lambda self, tx: VariableTracker.build(tx, True)
    )
    capturing = [False]
    monkeypatch.setattr(torch.cuda, "is_current_stream_capturing", lambda: capturing[0])
    torch._dynamo.reset()
    monkeypatch.setattr(torch._dynamo.config, "error_on_recompile", True)
    torch.manual_seed(0)
    up, down = SMPUp(3, 4, 8), SMPDown(4, (8,))
    # two robots of 4 limbs: a chain and a torso with three children
    parent = torch.tensor([[-1, 0, 1, 2], [-1, 0, 0, 0]])
    mask = torch.ones(2, 4, dtype=torch.bool)
    x = torch.randn(2, 4, 3)

    def passes(x, parent, mask):
        return down(up(x, parent, mask), parent, mask)

    compiled = torch.compile(passes, backend="aot_eager")
    try:
        eager = passes(x, parent, mask)
        first = compiled(x, parent, mask)
        capturing[0] = True
        second = compiled(x, parent, mask)  # a recompile raises here
    finally:
        torch._dynamo.reset()
    torch.testing.assert_close(first, eager)
    torch.testing.assert_close(second, eager)


class _TreeStep:
    """A step whose output lives in one buffer that its next call overwrites, as a step run in
    CUDA graph trees (``compile.mode=reduce-overhead``) returns it."""

    def __init__(self, key: str) -> None:
        self.key, self.calls, self.out = key, 0, torch.zeros(())

    def __call__(self, batch):
        self.calls += 1
        self.out.fill_(float(self.calls))
        return {self.key: self.out}


def test_losses_of_a_phase_outlive_the_steps_of_cuda_graph_trees():
    """TD3 reads the losses of a phase's steps at its end: a step run in CUDA graph trees has
    overwritten its earlier outputs by then, unless each step's losses were taken out."""
    learner = SimpleNamespace(
        accel=CompileConfig(compile=True, mode="reduce-overhead"),
        config=SimpleNamespace(policy_delay=2),
        updates=0,
        critic_step=_TreeStep("loss_critic"),
        actor_step=_TreeStep("loss_actor"),
    )
    rows = loss_rows([delayed_update(learner, None) for _ in range(4)])
    assert [r["loss_critic"] for r in rows] == [1.0, 2.0, 3.0, 4.0]
    assert [r.get("loss_actor") for r in rows] == [None, 1.0, None, 2.0]
