"""The ``compile:`` recipe switches applied to an algorithm's update steps and to the collector.

For any algorithm (TD3 uses it; PPO can call the same helpers)::

    loss = compile_step(critic_loss, recipe.compile, fullgraph=True)  # the loss forward compiled
    step = accelerate(critic_step, recipe.compile)      # the whole step in a CUDA graph
    with autocast(recipe.compile, device):              # bf16 when compile.amp
        ...
    begin_step(recipe.compile)                          # before each call of a graphed step
    Collector(..., **collector_kwargs(recipe.compile))  # compile_policy / cudagraph_policy

A step given to :func:`accelerate` must keep static shapes and hold no Python branch on data:
a CUDA graph freezes whatever a Python value was at capture, so a step that sometimes updates the
actor is two steps (one graph each), called as the schedule decides. A graphed step takes and
returns TensorDicts (or tensors) and must be called with tensors of the same shapes every time.
With every switch off (the default, and the only choice on a CPU for the CUDA ones), each helper
returns its input unchanged.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from gcnt.envs.stepper import usable_cpus
from gcnt.recipes import CompileConfig

log = logging.getLogger(__name__)


def inductor_cache_dir(config: CompileConfig) -> Path:
    """Where compiled code is cached: ``compile.cache_dir``, else ``$TORCHINDUCTOR_CACHE_DIR``
    when the user set it, else ``$XDG_CACHE_HOME/gcnt/inductor`` (``~/.cache/gcnt/inductor``);
    never inductor's own default, a folder under the shared ``/tmp``. Importing
    ``torch._dynamo`` (which torchrl does) writes that default into
    ``$TORCHINDUCTOR_CACHE_DIR`` itself, so the variable holding exactly inductor's default counts
    as unset."""
    if config.cache_dir:
        return Path(config.cache_dir).expanduser()
    from torch._inductor.runtime.cache_dir_utils import default_cache_dir

    users = os.environ.get("TORCHINDUCTOR_CACHE_DIR")
    if users and Path(users) != Path(default_cache_dir()):
        return Path(users)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "gcnt" / "inductor"


class _Timed:
    """A compiled function that logs how long its first call took (the compilation's time) and
    keeps the seconds in :attr:`compile_s`."""

    def __init__(self, fn: Callable, name: str, what: str = "compiled in") -> None:
        self.fn, self.name, self.what = fn, name, what
        self.compile_s: float | None = None

    def __call__(self, *args, **kwargs):
        if self.compile_s is not None:
            return self.fn(*args, **kwargs)
        start = time.perf_counter()
        out = self.fn(*args, **kwargs)
        self.compile_s = time.perf_counter() - start
        log.info("torch.compile: %s %s %.1f s", self.name, self.what, self.compile_s)
        return out


def compile_step(
    fn: Callable, config: CompileConfig, *, fullgraph: bool = False, name: str | None = None
) -> Callable:
    """``torch.compile(fn)`` when ``compile.compile`` (with ``compile.mode``; ``fullgraph``: a
    graph break is an error), else ``fn`` (``compile.compile`` still ``auto`` here is eager: an
    algorithm with a rule resolves it first, :func:`choose_compile`). Compiled code is cached in
    :func:`inductor_cache_dir`; the first call's time is logged."""
    if config.compile is not True:
        return fn
    kwargs: dict[str, Any] = {"fullgraph": fullgraph}
    if config.mode and config.mode != "default":
        kwargs["mode"] = config.mode
    cache = inductor_cache_dir(config)
    cache.mkdir(parents=True, exist_ok=True)
    os.environ["TORCHINDUCTOR_CACHE_DIR"] = str(cache.resolve())
    return _Timed(torch.compile(fn, **kwargs), name or getattr(fn, "__name__", "step"))


#: ``compile.compile: auto`` keeps an update eager on a CPU with 2 to 4 cores when its network
#: has at least this many parameters (the actor's): such an update is bound by its matrix
#: products, not by its operators, and eagerly runs its twin critics, target actor and actor
#: halves on two threads where the compiled one runs on one. Measured on 2-core machines: the
#: quick start's and study 1's networks (actors of about 14k parameters) update 0.57-0.80x
#: eager's time compiled; the paper's Walker++ sizes (GCNT's actor 413k) 1.25x slower compiled
#: (docs/performance.md)
ARITHMETIC_BOUND_PARAMS = 100_000


def choose_compile(
    config: CompileConfig,
    device: str | torch.device,
    planned_updates: float,
    break_even_updates: float,
    params: int | None = None,
) -> tuple[bool, str]:
    """``compile.compile`` for a run, and why: a bool as the recipe gives it; ``auto``: compiled
    on a CPU when the run plans at least ``break_even_updates`` updates (the updates whose
    saving repays the compile time, measured by the algorithm), eager below that, on other
    devices (not measured), where ``compile.twin_threads=true`` asks for the eager two-thread
    critics, and on a CPU with 2 to 4 cores for a network of ``params`` parameters or more
    than :data:`ARITHMETIC_BOUND_PARAMS` (bound by its arithmetic: eager uses both cores)."""
    if config.compile is not True and config.compile is not False:
        if config.twin_threads:
            return False, "auto: eager, as compile.twin_threads=true runs the critics eagerly"
        if torch.device(device).type != "cpu":
            return False, f"auto: eager on {device} (the break-even was measured on CPUs)"
        if (
            params is not None
            and params >= ARITHMETIC_BOUND_PARAMS
            and 2 <= usable_cpus() <= 4
            and config.torch_threads in (None, 1)
        ):
            return False, (
                f"auto: eager, the network ({params:,} parameters) is bound by its arithmetic "
                f"and this CPU has {usable_cpus()} cores: eager runs the update on two threads, "
                "compiled on one"
            )
        if planned_updates >= break_even_updates:
            return True, (
                f"auto: compiled, the run plans {planned_updates:,.0f} updates, past the "
                f"{break_even_updates:,.0f} that repay the compile time"
            )
        return False, (
            f"auto: eager, the run plans {planned_updates:,.0f} updates, fewer than the "
            f"{break_even_updates:,.0f} that repay the compile time"
        )
    return bool(config.compile), f"{str(config.compile).lower()} (the recipe's)"


#: relative error of a float32 product above which "medium" is taken to round to bfloat16
#: (float32: ~1e-6; bfloat16's 8-bit mantissa: ~1e-3)
BF16_ERROR = 1e-4


@functools.cache
def medium_keeps_float32() -> bool:
    """Whether ``set_float32_matmul_precision("medium")`` keeps float32's accuracy on this CPU:
    a 256 x 256 x 256 product of fixed random matrices under it, against float64 (oneDNN rounds
    the operands to bfloat16 where the CPU has AMX or AVX512-BF16). Torch's setting is restored
    afterwards."""
    before = torch.get_float32_matmul_precision()
    gen = torch.Generator().manual_seed(0)
    a, b = (torch.randn(256, 256, generator=gen) for _ in range(2))
    exact = a.double() @ b.double()
    try:
        torch.set_float32_matmul_precision("medium")
        error = ((a @ b).double() - exact).abs().max() / exact.abs().max()
    finally:
        torch.set_float32_matmul_precision(before)
    return bool(error < BF16_ERROR)


def choose_matmul_precision(config: CompileConfig, device: str | torch.device) -> tuple[str, str]:
    """``compile.matmul_precision`` for a run, and why: as the recipe names it; ``auto``: on a CPU
    "medium" where :func:`medium_keeps_float32`, "highest" where it would round to bfloat16;
    "highest" on other devices (TF32 changes a GPU's float32 results)."""
    if config.matmul_precision != "auto":
        return config.matmul_precision, "the recipe's"
    if torch.device(device).type != "cpu":
        return "highest", f"auto: float32 products on {device}"
    if medium_keeps_float32():
        return "medium", "auto: this CPU's oneDNN products keep float32 accuracy"
    return "highest", "auto: medium would round this CPU's products to bfloat16"


def timed_first_call(fn: Callable, config: CompileConfig, name: str) -> Callable:
    """A step that calls compiled losses, with its first call's time logged when
    ``compile.compile``: the whole compile time, as AOTAutograd compiles a loss's backward graph
    at the first backward, after the forward's logged time; ``fn`` itself otherwise."""
    if config.compile is not True:
        return fn
    return _Timed(fn, name, "first call (its graphs' forward and backward compiled) in")


def compile_seconds(*fns: Callable) -> float:
    """The seconds the first calls of the compiled ``fns`` took (0 for one not compiled or not
    called yet)."""
    return sum(getattr(f, "compile_s", None) or 0.0 for f in fns)


def cudagraph_step(fn: Callable, config: CompileConfig, device: str | torch.device) -> Callable:
    """``fn`` captured in a CUDA graph after ``compile.warmup`` eager calls, when
    ``compile.cudagraphs`` (CUDA only; the recipe check rejects it on a CPU)."""
    if not config.cudagraphs:
        return fn
    if torch.device(device).type != "cuda":
        raise ValueError(f"compile.cudagraphs=true needs a CUDA device, got {device}")
    from tensordict.nn import CudaGraphModule

    return CudaGraphModule(fn, warmup=config.warmup, in_keys=[], out_keys=[], device=device)


def accelerate(fn: Callable, config: CompileConfig, device: str | torch.device) -> Callable:
    """:func:`cudagraph_step` of a whole update step. What ``compile.compile`` compiles is the
    step's loss forward (:func:`compile_step` with ``fullgraph``: one graph, its backward through
    AOTAutograd), not the step: torch's optimisers break the graph on purpose around their
    ``step``, which runs eagerly (one fused kernel)."""
    return cudagraph_step(fn, config, device)


#: torch.compile modes whose compiled steps run in CUDA graph trees: a step's outputs live in the
#: tree's memory pool and are overwritten by a later step
CUDAGRAPH_TREE_MODES = ("reduce-overhead", "max-autotune")


def owned(outputs: dict[str, torch.Tensor], config: CompileConfig) -> dict[str, torch.Tensor]:
    """A step's outputs that outlive the next step: cloned out of the CUDA graph trees' memory
    when ``compile.mode`` runs them there (a phase reads all its steps' losses at its end),
    ``outputs`` itself otherwise."""
    if config.compile is True and config.mode in CUDAGRAPH_TREE_MODES:
        return {k: v.clone() for k, v in outputs.items()}
    return outputs


def begin_step(config: CompileConfig) -> None:
    """Mark a new step for CUDA-graphed code (call before each graphed step; a no-op else)."""
    if config.cudagraphs or config.policy_cudagraphs:
        torch.compiler.cudagraph_mark_step_begin()


def autocast(config: CompileConfig, device: str | torch.device):
    """bfloat16 autocast on the update's device when ``compile.amp``; else a null context."""
    if not config.amp:
        return contextlib.nullcontext()
    return torch.autocast(torch.device(device).type, dtype=torch.bfloat16)


def collector_kwargs(config: CompileConfig) -> dict[str, Any]:
    """The collector's ``compile_policy`` / ``cudagraph_policy`` arguments (empty when off)."""
    out: dict[str, Any] = {}
    if config.policy_compile:
        out["compile_policy"] = {"mode": config.mode} if config.mode else True
    if config.policy_cudagraphs:
        out["cudagraph_policy"] = {"warmup": config.warmup}
    return out


def optimizer_kwargs(config: CompileConfig, device: str | torch.device) -> dict[str, Any]:
    """Adam/AdamW options: ``capturable`` for a graphed step; the fused kernel of a CPU or a
    CUDA device otherwise (one call for all parameters instead of one per parameter or
    group); the optimiser step runs eagerly under ``compile.compile`` too (see
    :func:`accelerate`)."""
    if config.cudagraphs:
        return {"capturable": True}
    if torch.device(device).type in ("cpu", "cuda"):
        return {"fused": True}
    return {}
