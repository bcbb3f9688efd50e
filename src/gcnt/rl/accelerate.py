"""The ``compile:`` recipe switches applied to an algorithm's update steps and to the collector.

For any algorithm (TD3 uses it; PPO can call the same helpers)::

    step = accelerate(critic_step, recipe.compile)      # torch.compile, then a CUDA graph
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
import logging
from collections.abc import Callable
from typing import Any

import torch

from gcnt.recipes import CompileConfig

log = logging.getLogger(__name__)


def compile_step(fn: Callable, config: CompileConfig) -> Callable:
    """``torch.compile(fn)`` when ``compile.compile`` (with ``compile.mode``), else ``fn``."""
    if not config.compile:
        return fn
    kwargs: dict[str, Any] = {}
    if config.mode and config.mode != "default":
        kwargs["mode"] = config.mode
    return torch.compile(fn, **kwargs)


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
    """:func:`compile_step` then :func:`cudagraph_step` (the sota-implementations' order)."""
    return cudagraph_step(compile_step(fn, config), config, device)


#: torch.compile modes whose compiled steps run in CUDA graph trees: a step's outputs live in the
#: tree's memory pool and are overwritten by a later step
CUDAGRAPH_TREE_MODES = ("reduce-overhead", "max-autotune")


def owned(outputs: dict[str, torch.Tensor], config: CompileConfig) -> dict[str, torch.Tensor]:
    """A step's outputs that outlive the next step: cloned out of the CUDA graph trees' memory
    when ``compile.mode`` runs them there (a phase reads all its steps' losses at its end),
    ``outputs`` itself otherwise."""
    if config.compile and config.mode in CUDAGRAPH_TREE_MODES:
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
    group); torch's choice (foreach) under ``compile.compile``."""
    if config.cudagraphs:
        return {"capturable": True}
    if torch.device(device).type in ("cpu", "cuda") and not config.compile:
        return {"fused": True}
    return {}
