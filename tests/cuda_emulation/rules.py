"""CUDA's device rules, applied to every aten op (forward, autograd backward, optimiser kernels),
and the recording of a capture. Tensors are real CPU tensors: an op runs on them as given, and
its new outputs live on the emulated GPU when the op runs there."""

from __future__ import annotations

import warnings

import torch
from torch.utils._python_dispatch import TorchDispatchMode

from . import state
from .state import CUDA, EmulationError, local, on_gpu, storage_of

aten = torch.ops.aten

#: ops that are no TensorIterator: every tensor must be on the op's device, 0-dim ones too
STRICT = {
    aten.cat, aten.stack, aten.index_select, aten.mm, aten.addmm, aten.bmm, aten.baddbmm,
    aten.mv, aten.addmv, aten.embedding, aten.embedding_dense_backward, aten.linear,
    aten.matmul, aten.gather, aten.scatter, aten.scatter_add, aten.scatter_add_, aten.scatter_,
    aten.index_add, aten.index_add_, aten._embedding_bag,
}  # fmt: skip
#: ops that move data between devices, or whose indices may live on the host
CROSSING = {
    aten.copy_, aten._to_copy, aten.lift_fresh, aten.lift_fresh_copy, aten.detach,
    aten.alias, aten._foreach_copy_, aten.set_, aten._local_scalar_dense,
}  # fmt: skip
INDEXING = {aten.index, aten.index_put_, aten.index_put, aten._index_put_impl_}
#: ops whose output size depends on values: they synchronise, which a capture forbids
DATA_DEPENDENT = {aten.nonzero, aten.masked_select, aten._unique2, aten.unique_dim,
                  aten.unique_consecutive, aten.repeat_interleave}  # fmt: skip
#: ops that read no data (shapes, aliasing checks)
METADATA = {aten.sym_size, aten.sym_stride, aten.sym_numel, aten.sym_storage_offset,
            aten.is_same_size, aten._has_compatible_shallow_copy_type}  # fmt: skip


def _mixing(what: str, a: torch.Tensor, b: torch.Tensor) -> EmulationError:
    return EmulationError(
        f"Expected all tensors to be on the same device, but found at least two devices, "
        f"cuda:0 and cpu! ({what}: shapes {tuple(a.shape)} and {tuple(b.shape)})"
    )


def _capture_error(what: str) -> EmulationError:
    return EmulationError(f"CUDA error: operation not permitted when stream is capturing ({what})")


def _check_group(func, tensors: list[torch.Tensor], strict: bool) -> bool:
    """Raise where CUDA raises for ``tensors`` of one op (or one foreach element); whether the
    group runs on the GPU."""
    gpu = [t for t in tensors if on_gpu(t)]
    if not gpu:
        return False
    for t in tensors:
        if not on_gpu(t) and (strict or t.dim() > 0):
            raise _mixing(str(func), gpu[0], t)
    return True


class DeviceRules(TorchDispatchMode):
    """Raises where CUDA raises, tags new outputs of GPU ops, and records them in a capture."""

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        packet = func.overloadpacket
        if packet in METADATA:
            return func(*args, **kwargs)
        inputs = _tensors(args, kwargs.values())
        moving = local.moving
        if moving is not None:  # an explicit move or a factory with a device
            gpu = moving.type == "cuda"
        elif packet in INDEXING:
            gpu = self._indexing(func, args)
        elif packet in CROSSING:
            gpu = bool(inputs) and on_gpu(inputs[0])
        elif str(packet).startswith("aten._foreach") or str(packet).startswith("aten._fused"):
            return self._foreach(func, args, kwargs)
        else:
            gpu = _check_group(func, inputs, packet in STRICT)
        cap = state.capture[0]
        if cap is not None and (gpu or any(on_gpu(t) for t in inputs)):
            self._capture_rules(func, packet, args, inputs, kwargs, moving)
            return self._recorded(cap, func, args, kwargs, inputs)
        out = func(*args, **kwargs)
        if gpu:
            _tag_new(out, inputs)
        elif moving is not None or packet in CROSSING:
            _untag_new(out, inputs)
        if cap is not None:  # a host tensor made while capturing (a constant of the step)
            for t in _new_outputs(out, inputs):
                if (s := storage_of(t)) is not None:
                    cap.allocated[s] = True
        return out

    # ------------------------------------------------------------------ op families
    def _indexing(self, func, args) -> bool:
        """``gpu_table[cpu_index]`` runs on the GPU; ``cpu_table[gpu_index]`` raises."""
        table, indices = args[0], [i for i in args[1] if i is not None]
        if on_gpu(table):
            if func.overloadpacket is not aten.index and len(args) > 2:
                _check_group(func, [table, args[2]], strict=False)  # the values put
            return True
        for i in indices:
            if on_gpu(i):
                raise _mixing(f"{func} with a cpu table", i, table)
        return False

    def _foreach(self, func, args, kwargs):
        """Foreach and fused kernels: each element's tensors on one device."""
        lists = [a for a in (*args, *kwargs.values()) if isinstance(a, (list, tuple))]
        lists = [a for a in lists if a and all(isinstance(t, torch.Tensor) for t in a)]
        single = [a for a in (*args, *kwargs.values()) if isinstance(a, torch.Tensor)]
        n = len(lists[0]) if lists else 0
        gpu = [
            _check_group(func, [lst[i] for lst in lists] + single, strict=False) for i in range(n)
        ]
        cap = state.capture[0]
        inputs = [t for lst in lists for t in lst] + single
        if cap is not None and any(gpu):
            self._capture_rules(func, func.overloadpacket, args, inputs, kwargs, None)
            return self._recorded(cap, func, args, kwargs, inputs)
        out = func(*args, **kwargs)
        if isinstance(out, (list, tuple)) and len(out) == n:
            for o, g in zip(out, gpu, strict=True):
                if g and isinstance(o, torch.Tensor):
                    _tag_new(o, inputs)
        return out

    # ------------------------------------------------------------------ capture
    def _capture_rules(self, func, packet, args, inputs, kwargs, moving) -> None:
        if packet is aten._local_scalar_dense:
            if local.host_reads_allowed:
                return
            raise _capture_error(f"a host read of a CUDA tensor ({func}: .item(), bool(), int())")
        if packet in DATA_DEPENDENT:
            raise _capture_error(f"{func} synchronises (its output size depends on values)")
        if packet in INDEXING and any(
            i is not None and i.dtype in (torch.bool, torch.uint8) for i in args[1]
        ):
            raise _capture_error(f"boolean-mask indexing ({func}) calls nonzero")
        if moving is not None or packet in (aten.copy_, aten._foreach_copy_):
            devices = {on_gpu(t) for t in inputs}
            if moving is not None:
                devices.add(moving.type == "cuda")
            if len(devices) > 1:
                raise _capture_error(f"a copy between the host and the device ({func})")
        if kwargs.get("generator") is not None:
            raise _capture_error(f"{func} draws from a generator other than the default CUDA one")
        # a host scalar made before the capture may change after it; the graph keeps its value
        cap = state.capture[0]
        scalars = [t for t in inputs if not on_gpu(t) and t.dim() == 0 and _made_before(t, cap)]
        if scalars and packet not in CROSSING:
            warnings.warn(
                f"a captured kernel ({func}) reads a CPU scalar: its value at capture is frozen "
                "into the graph",
                stacklevel=2,
            )

    def _recorded(self, cap: state.Capture, func, args, kwargs, inputs):
        for arg, schema in zip(args, func._schema.arguments, strict=False):
            info = schema.alias_info
            if info is not None and info.is_write:
                for t in arg if isinstance(arg, (list, tuple)) else [arg]:
                    s = storage_of(t) if isinstance(t, torch.Tensor) else None
                    if s is not None:
                        cap.before_write(s)
        out = func(*args, **kwargs)
        fresh = _tag_new(out, inputs)
        for t in fresh:
            s = storage_of(t)
            if s is not None:
                cap.allocated[s] = True
        # a CPU scalar's value is frozen at capture, as a real graph bakes it in
        frozen_args, frozen_kwargs = _freeze((args, kwargs))
        cap.ops.append((func, frozen_args, frozen_kwargs, out, {id(t) for t in fresh}))
        return out


def _made_before(t: torch.Tensor, cap: state.Capture) -> bool:
    s = storage_of(t)
    return s is not None and s not in cap.allocated


def _tensors(*groups) -> list[torch.Tensor]:
    """The tensors of aten arguments (tensors, or lists of them)."""
    out = []
    for group in groups:
        for a in group:
            if isinstance(a, torch.Tensor):
                out.append(a)
            elif isinstance(a, (list, tuple)):
                out.extend(t for t in a if isinstance(t, torch.Tensor))
    return out


def _storage_id(t: torch.Tensor) -> int | None:
    try:
        return t.untyped_storage()._cdata
    except (RuntimeError, NotImplementedError, TypeError):
        return None


def _freeze(tree):
    if isinstance(tree, torch.Tensor):
        return tree.clone() if not on_gpu(tree) and tree.dim() == 0 else tree
    if isinstance(tree, (list, tuple)):
        return type(tree)(_freeze(x) for x in tree)
    if isinstance(tree, dict):
        return {k: _freeze(v) for k, v in tree.items()}
    return tree


def _new_outputs(out, inputs: list[torch.Tensor]) -> list[torch.Tensor]:
    """The tensors of ``out`` whose storage is none of ``inputs``' (aten level: no wrappers)."""
    flat = _tensors((out,))
    if not flat:
        return []
    old = {_storage_id(t) for t in inputs}
    return [t for t in flat if _storage_id(t) not in old]


def _tag_new(out, inputs) -> list[torch.Tensor]:
    fresh = _new_outputs(out, inputs)
    for t in fresh:
        state.tag(t)
    return fresh


def _untag_new(out, inputs) -> None:
    for t in _new_outputs(out, inputs):
        state.tag(t, gpu=False)


def replay(ops) -> None:
    """Re-execute recorded ops on the same tensors; new outputs are written into the tensors
    the capture returned (the graph's static memory)."""
    from torch.utils._python_dispatch import _disable_current_modes

    with torch.no_grad(), _disable_current_modes():
        for func, args, kwargs, out, fresh in ops:
            if func.is_view:
                continue  # the recorded view aliases its base already
            res = func(*args, **kwargs)
            recorded, new = _tensors((out,)), _tensors((res,))
            for o, r in zip(recorded, new, strict=False):
                if isinstance(o, torch.Tensor) and id(o) in fresh and r is not o:
                    o.copy_(r)


__all__ = ["CUDA", "DeviceRules", "replay"]
