"""What Python sees of a tensor on the emulated GPU: its device, moves between devices, factories
called with ``device='cuda'`` and the conversions CUDA refuses (NumPy) or forbids in a capture.
Moves and factories must be caught here: on a CPU-only torch they fail before any aten op."""

from __future__ import annotations

import contextlib

import torch
from torch.overrides import TorchFunctionMode

from . import state
from .rules import _new_outputs, _tensors
from .state import CPU, CUDA, EmulationError, is_cuda_device, local, on_gpu

T = torch.Tensor


@contextlib.contextmanager
def moving(device: torch.device | None):
    before, local.moving = local.moving, device
    try:
        yield
    finally:
        local.moving = before


def _capturing() -> bool:
    return state.capture[0] is not None


def _numpy_refused(self: torch.Tensor):
    return TypeError(
        "can't convert cuda:0 device type tensor to numpy. Use Tensor.cpu() to copy the tensor "
        "to host memory first."
    )


def _to(func, args, kwargs):
    self, rest = args[0], args[1:]
    if rest and isinstance(rest[0], torch.Tensor):  # .to(other): other's device and dtype
        other = rest[0]
        device, dtype = state.device_of(other), other.dtype
        non_blocking = bool(rest[1]) if len(rest) > 1 else kwargs.get("non_blocking", False)
        memory_format = kwargs.get("memory_format", torch.preserve_format)
    else:
        device, dtype, non_blocking, memory_format = torch._C._nn._parse_to(*rest, **kwargs)
    return _move(self, device, dtype, non_blocking, kwargs.get("copy", False), memory_format)


def _move(self, device, dtype=None, non_blocking=False, copy=False, memory_format=None):
    memory_format = torch.preserve_format if memory_format is None else memory_format
    kw = {"dtype": dtype, "non_blocking": non_blocking, "memory_format": memory_format}
    if device is None or (device.type == "cuda") == on_gpu(self):
        return T.to(self, copy=copy, **kw)
    target = CUDA if device.type == "cuda" else CPU
    with moving(target):
        return T.to(self, "cpu", copy=True, **kw)


def _cuda(func, args, kwargs):
    self = args[0]
    return _move(self, CUDA, None, kwargs.get("non_blocking", False), False,
                 kwargs.get("memory_format"))  # fmt: skip


def _cpu(func, args, kwargs):
    return _move(args[0], CPU, None, False, False, kwargs.get("memory_format"))


def _device(func, args, kwargs):
    return CUDA if on_gpu(args[0]) else func(*args, **kwargs)


def _is_cuda(func, args, kwargs):
    return on_gpu(args[0])


def _is_cpu(func, args, kwargs):
    return not on_gpu(args[0]) and func(*args, **kwargs)


def _get_device(func, args, kwargs):
    return 0 if on_gpu(args[0]) else func(*args, **kwargs)


def _numpy(func, args, kwargs):
    if on_gpu(args[0]):
        raise _numpy_refused(args[0])
    return func(*args, **kwargs)


def _tolist(func, args, kwargs):
    if on_gpu(args[0]) and _capturing():
        raise EmulationError(
            "CUDA error: operation not permitted when stream is capturing (tolist)"
        )
    return func(*args, **kwargs)


def _deepcopy(func, args, kwargs):
    out = func(*args, **kwargs)
    if on_gpu(args[0]):
        state.tag(out)
        if out.grad is not None and args[0].grad is not None and on_gpu(args[0].grad):
            state.tag(out.grad)
    return out


def _pin_memory(func, args, kwargs):
    if on_gpu(args[0]):
        raise EmulationError(
            "cannot pin 'torch.cuda.FloatTensor' only dense CPU tensors can be pinned"
        )
    return args[0]


def _host_reading_kernel(func, args, kwargs):
    local.host_reads_allowed += 1
    try:  # what the composite kernel allocates lives on its input's device
        with moving(CUDA if on_gpu(args[0]) else None):
            return func(*args, **kwargs)
    finally:
        local.host_reads_allowed -= 1


HANDLERS = {
    T.to: _to,
    T.cuda: _cuda,
    T.cpu: _cpu,
    T.device.__get__: _device,
    T.is_cuda.__get__: _is_cuda,
    T.is_cpu.__get__: _is_cpu,
    T.get_device: _get_device,
    T.numpy: _numpy,
    T.__array__: _numpy,
    T.tolist: _tolist,
    T.__deepcopy__: _deepcopy,
    T.pin_memory: _pin_memory,
    T.is_pinned: lambda func, args, kwargs: False,
    # CPU kernels that read values where CUDA's do not (one_hot checks its range on the host)
    torch.nn.functional.one_hot: _host_reading_kernel,
}
_NEW = {T.new_tensor, T.new_zeros, T.new_ones, T.new_empty, T.new_full}


class PythonSide(TorchFunctionMode):
    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        handler = HANDLERS.get(func)
        if handler is not None:
            return handler(func, args, kwargs)
        device = kwargs.get("device")
        if device is not None and not isinstance(device, torch.Tensor):
            gpu = is_cuda_device(device)
            with moving(CUDA if gpu else CPU):
                out = func(*args, **{**kwargs, "device": "cpu"})
            # some factories (torch.tensor) build their tensor below the dispatch modes
            inputs = [state.plain(a) for a in _tensors(args)]
            for t in _new_outputs(out, inputs):
                state.tag(t, gpu)
            return out
        if func in _NEW and on_gpu(args[0]):
            with moving(CUDA):
                return func(*args, **kwargs)
        return func(*args, **kwargs)
