"""CUDA's semantics on a CPU-only torch, for tests of the GPU path on machines without a GPU.

Tensors stay real CPU tensors, so a whole program runs and produces values; the storages that
live on the emulated GPU are tagged (:mod:`.state`). Four pieces:

* :mod:`.rules`: a dispatch mode that sees every aten op, raises where CUDA raises (mixing
  devices, host reads and syncs inside a capture) and tags the new outputs of GPU ops;
* :mod:`.frontend`: a function mode that fakes what Python sees (``.device``, ``.is_cuda``,
  ``.to('cuda')``, ``.cpu()``, ``.numpy()``, factories with ``device='cuda'``);
* :mod:`.patches`: ``torch.cuda`` / ``torch.accelerator`` entry points, RNG state, checkpoints,
  autocast and torch's grouping of tensors by device;
* :mod:`.graphs`: ``torch.cuda.graph`` / ``CUDAGraph`` with capture rules, record and replay.

Blind spots: ``torch.compile`` (dynamo skips frames under a dispatch mode, so compiled code runs
eagerly here), kernels, dtype support, numerics, memory, streams, other threads (the modes are
per thread) and the gradient of ``.cpu()`` (it stays on the host here).

Usage::

    with emulate():
        x = torch.ones(3, device="cuda")   # x.device == cuda:0; x.numpy() raises
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from . import graphs, patches, state
from .frontend import PythonSide
from .rules import DeviceRules
from .state import CUDA, EmulationError, on_gpu, tag

__all__ = ["CUDA", "EmulationError", "active", "emulate", "graphs", "on_gpu", "tag"]

_active = [False]


def active() -> bool:
    return _active[0]


@contextlib.contextmanager
def emulate() -> Iterator[None]:
    """The emulated GPU, inside: ``torch.cuda.is_available()`` is True."""
    if _active[0]:
        yield
        return
    # imported as on a CPU build (it asks whether torch was built with CUDA, and torch says no)
    import torch._inductor.cudagraph_trees  # noqa: F401

    # tensordict's CudaGraphModule takes TensorDicts out of torch's pytree for the process; they
    # go back on exit, so that later tests see the process as they would without a GPU
    from torch.utils._pytree import SUPPORTED_NODES

    nodes = dict(SUPPORTED_NODES)
    saved = []
    for owner, name, repl in patches.entry_points():
        saved.append((owner, name, owner.__dict__.get(name, _MISSING)))
        setattr(owner, name, repl)
    _active[0] = True
    try:
        with PythonSide(), DeviceRules():
            yield
    finally:
        _active[0] = False
        state.capture[0] = None
        for kind, node in nodes.items():
            SUPPORTED_NODES.setdefault(kind, node)
        for owner, name, old in reversed(saved):
            if old is _MISSING:
                delattr(owner, name)
            else:
                setattr(owner, name, old)


_MISSING = object()
