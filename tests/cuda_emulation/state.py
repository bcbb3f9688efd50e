"""Which storages live on the emulated GPU, and the capture in progress (one per process)."""

from __future__ import annotations

import threading
import weakref

import torch

CUDA = torch.device("cuda", 0)
CPU = torch.device("cpu")

#: untyped storages that live on the emulated GPU (weakly held: a freed storage drops out)
_on_gpu: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


class EmulationError(RuntimeError):
    """What real CUDA raises where the emulation raises (a RuntimeError, as torch's)."""


class _Local(threading.local):
    #: the device an explicit ``.to()`` / ``.cuda()`` / ``.cpu()`` moves its copy to
    moving: torch.device | None = None
    #: inside a CPU kernel that reads values where CUDA's does not (e.g. one_hot's range check)
    host_reads_allowed: int = 0


local = _Local()


class Capture:
    """The graph being captured: every CUDA op in order, the storages allocated inside (the
    graph's pool) and a copy of each pre-existing storage before the capture first wrote it."""

    def __init__(self, graph) -> None:
        self.graph = graph
        self.ops: list = []
        self.allocated: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
        self.saved: list[tuple[torch.UntypedStorage, torch.UntypedStorage]] = []
        self._saved_keys: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()

    def before_write(self, storage: torch.UntypedStorage) -> None:
        if storage in self.allocated or storage in self._saved_keys:
            return
        self._saved_keys[storage] = True
        self.saved.append((storage, storage.clone()))

    def roll_back(self) -> None:
        """A real capture runs no kernel: undo what the capture wrote to older memory."""
        for storage, copy in self.saved:
            storage.copy_(copy)
        self.saved.clear()


#: the capture in progress, or None
capture: list[Capture | None] = [None]


def plain(t: torch.Tensor) -> torch.Tensor:
    """``t`` without functorch's vmap / grad wrappers (they own no storage)."""
    f = torch._C._functorch
    while f.is_batchedtensor(t) or f.is_gradtrackingtensor(t):
        t = f.get_unwrapped(t)
    return t


def storage_of(t: torch.Tensor) -> torch.UntypedStorage | None:
    try:
        return t.untyped_storage()
    except (RuntimeError, NotImplementedError, TypeError):
        pass
    try:  # a functorch wrapper
        return plain(t).untyped_storage()
    except (RuntimeError, NotImplementedError, TypeError):
        return None


def on_gpu(t: torch.Tensor) -> bool:
    s = storage_of(t)
    return s is not None and s in _on_gpu


def tag(t: torch.Tensor, gpu: bool = True) -> torch.Tensor:
    """Put (``gpu``) or take ``t``'s storage on/off the emulated GPU; returns ``t``."""
    s = storage_of(t)
    if s is not None:
        if gpu:
            _on_gpu[s] = True
        else:
            _on_gpu.pop(s, None)
    return t


def device_of(t: torch.Tensor) -> torch.device:
    return CUDA if on_gpu(t) else t.device


def is_cuda_device(device) -> bool:
    if device is None or isinstance(device, torch.Tensor):
        return False
    if isinstance(device, int):
        return True  # a bare index means a CUDA device, as in torch
    try:
        return torch.device(device).type == "cuda"
    except (RuntimeError, TypeError):
        return False
