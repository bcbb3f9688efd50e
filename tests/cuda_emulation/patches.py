"""The ``torch.cuda`` / ``torch.accelerator`` entry points of one emulated GPU, and the places
where torch decides a device from what it was told rather than from a tensor: RNG state,
checkpoints, autocast and the grouping of tensors by device for foreach kernels."""

from __future__ import annotations

import types

import torch
from torch.utils._pytree import tree_leaves

from . import graphs, state
from .state import CPU, CUDA, is_cuda_device, on_gpu

_PROPS = types.SimpleNamespace(
    name="emulated CUDA device (CPU tensors)",
    total_memory=80 * 2**30,
    major=9,
    minor=0,
    multi_processor_count=132,
    is_integrated=False,
    is_multi_gpu_board=False,
)
_cuda_rng = {"state": None}


def _check_rng_state(new_state) -> None:
    if (
        not isinstance(new_state, torch.Tensor)
        or on_gpu(new_state)
        or (new_state.dtype != torch.uint8)
    ):
        raise TypeError("RNG state must be a torch.ByteTensor")


def _set_rng_state(original):
    def set_rng_state(new_state, *args, **kwargs):
        _check_rng_state(new_state)
        return original(new_state, *args, **kwargs)

    return set_rng_state


def cuda_get_rng_state(device="cuda"):
    if _cuda_rng["state"] is None:
        _cuda_rng["state"] = torch.zeros(16, dtype=torch.uint8)
    return _cuda_rng["state"].clone()


def cuda_set_rng_state(new_state, device="cuda") -> None:
    _check_rng_state(new_state)
    _cuda_rng["state"] = new_state.clone()


def _tag_tree(obj):
    for x in tree_leaves(obj):
        if isinstance(x, torch.Tensor):
            state.tag(x)
    return obj


def _load(original):
    def load(f, map_location=None, *args, **kwargs):
        if map_location is None:
            # a storage saved from the emulated GPU comes back there, as on a GPU machine
            def restore(storage, location):
                if str(location).startswith("cuda"):
                    state._on_gpu[storage] = True
                return storage

            return original(f, restore, *args, **kwargs)
        if is_cuda_device(map_location):
            return _tag_tree(original(f, "cpu", *args, **kwargs))
        return original(f, map_location, *args, **kwargs)

    return load


def _location_tag(original):
    def location_tag(storage):
        s = storage._untyped_storage if isinstance(storage, torch.TypedStorage) else storage
        if isinstance(s, torch.UntypedStorage) and s in state._on_gpu:
            return "cuda:0"
        return original(storage)

    return location_tag


def _autocast(original):
    class autocast(original):  # noqa: N801 (torch's name)
        def __init__(self, device_type, *args, **kwargs):
            super().__init__("cpu" if device_type == "cuda" else device_type, *args, **kwargs)

    return autocast


def _group(original):
    """torch's grouping of tensor lists by (device, dtype), split by emulated device."""

    def group(tensorlistlist, with_indices=False):
        out = original(tensorlistlist, with_indices)
        split = {}
        for (device, dtype), (lists, indices) in out.items():
            if device.type != "cpu":
                split[(device, dtype)] = (lists, indices)
                continue
            first = lists[0]
            for gpu in (False, True):
                keep = [i for i, t in enumerate(first) if (t is not None and on_gpu(t)) == gpu]
                if not keep:
                    continue
                key = (CUDA if gpu else CPU, dtype)
                split[key] = (
                    [[lst[i] for i in keep] if lst else lst for lst in lists],
                    [indices[i] for i in keep] if indices else indices,
                )
        return split

    return group


def current_accelerator(check_available: bool = False) -> torch.device:
    return CUDA


def entry_points() -> list[tuple[object, str, object]]:
    """(owner, attribute, replacement) for every patched entry point."""
    c = torch.cuda
    # fmt: off
    repl = [
        (c, "is_available", lambda: True),
        (c, "is_initialized", lambda: True),
        (c, "_lazy_init", lambda: None),
        (c, "init", lambda: None),
        (c, "device_count", lambda: 1),
        (c, "current_device", lambda: 0),
        (c, "set_device", lambda device: None),
        (c, "get_device_name", lambda device=None: _PROPS.name),
        (c, "get_device_properties", lambda device=None: _PROPS),
        (c, "get_device_capability", lambda device=None: (_PROPS.major, _PROPS.minor)),
        (c, "is_bf16_supported", lambda including_emulation=True: True),
        (c, "synchronize", graphs.synchronize),
        (c, "Stream", graphs.Stream),
        (c, "Event", graphs.Event),
        (c, "stream", graphs.stream),
        (c, "current_stream", graphs.current_stream),
        (c, "default_stream", graphs.current_stream),
        (c, "graph", graphs.graph),
        (c, "CUDAGraph", graphs.CUDAGraph),
        (c, "graph_pool_handle", graphs.graph_pool_handle),
        (c, "is_current_stream_capturing", graphs.is_current_stream_capturing),
        (c, "manual_seed", lambda seed: None),
        (c, "manual_seed_all", lambda seed: None),
        (c, "seed", lambda: None),
        (c, "seed_all", lambda: None),
        (c, "get_rng_state", cuda_get_rng_state),
        (c, "set_rng_state", cuda_set_rng_state),
        (c, "get_rng_state_all", lambda: [cuda_get_rng_state()]),
        (c, "set_rng_state_all", lambda states: [cuda_set_rng_state(s) for s in states]),
        (c, "memory_allocated", lambda device=None: 0),
        (c, "max_memory_allocated", lambda device=None: 0),
        (c, "reset_peak_memory_stats", lambda device=None: None),
        (c, "empty_cache", lambda: None),
        (c, "mem_get_info", lambda device=None: (_PROPS.total_memory, _PROPS.total_memory)),
        (c, "set_sync_debug_mode", lambda mode: None),
        (c, "get_sync_debug_mode", lambda: 0),
        (torch.accelerator, "is_available", lambda: True),
        (torch.accelerator, "current_accelerator", current_accelerator),
        (torch.accelerator, "device_count", lambda: 1),
        (torch.accelerator, "current_device_index", lambda: 0),
        (torch.accelerator, "current_device_idx", lambda: 0),
        (torch.accelerator, "set_device_index", lambda device: None),
        (torch.accelerator, "set_device_idx", lambda device: None),
        (torch.accelerator, "current_stream", graphs.current_stream),
        (torch.accelerator, "synchronize", graphs.synchronize),
        (torch, "set_rng_state", _set_rng_state(torch.set_rng_state)),
        (torch.random, "set_rng_state", _set_rng_state(torch.random.set_rng_state)),
        (torch, "load", _load(torch.load)),
        (torch.serialization, "location_tag", _location_tag(torch.serialization.location_tag)),
        (torch, "autocast", _autocast(torch.autocast)),
        (torch.amp, "autocast", _autocast(torch.amp.autocast)),
        (torch._C, "_group_tensors_by_device_and_dtype",
         _group(torch._C._group_tensors_by_device_and_dtype)),
    ]
    # fmt: on
    return repl
