"""The emulated GPU of ``tests/cuda_emulation`` follows CUDA's rules (each case below is what
real CUDA does). These run before any test and again, once, before the first ``gpu`` test of a
session (``require_self_test``): a torch upgrade that changes the internals the emulation leans
on fails here, loudly, instead of letting the GPU tests pass without checking anything."""

from __future__ import annotations

import copy
import io
import warnings

import numpy as np
import pytest
import torch
from cuda_emulation import EmulationError, emulate, on_gpu

RULES = {}


def rule(fn):
    RULES[fn.__name__] = fn
    return fn


def raises(exc, fn) -> None:
    try:
        fn()
    except exc:
        return
    raise AssertionError(f"{fn} did not raise {exc.__name__}")


def gpu(*shape, **kw) -> torch.Tensor:
    return torch.ones(*shape, device="cuda", **kw)


@rule
def elementwise_with_a_cpu_tensor_raises():
    raises(RuntimeError, lambda: gpu(3) + torch.ones(3))


@rule
def elementwise_with_a_cpu_0dim_tensor_is_allowed():
    out = gpu(3) * torch.tensor(2.0)
    assert out.device.type == "cuda" and out.is_cuda


@rule
def stack_cat_index_select_mm_embedding_refuse_cpu_0dim():
    a, b = gpu(()), torch.tensor(1.0)
    raises(RuntimeError, lambda: torch.stack([a, b]))
    raises(RuntimeError, lambda: torch.cat([gpu(2), torch.ones(2)]))
    raises(RuntimeError, lambda: gpu(4, 2).index_select(0, torch.tensor([1])))
    raises(RuntimeError, lambda: gpu(2, 2) @ torch.ones(2, 2))
    raises(RuntimeError, lambda: torch.nn.functional.embedding(torch.tensor([0]), gpu(2, 2)))


@rule
def gpu_table_with_cpu_index_is_allowed():
    assert gpu(4, 2)[torch.tensor([0, 3])].is_cuda


@rule
def cpu_table_with_gpu_index_raises():
    raises(RuntimeError, lambda: torch.ones(4)[torch.tensor([1], device="cuda")])


@rule
def a_gpu_linear_refuses_a_cpu_input():
    lin = torch.nn.Linear(2, 2).to("cuda")
    assert lin.weight.is_cuda and lin(gpu(2)).is_cuda
    raises(RuntimeError, lambda: lin(torch.ones(2)))


@rule
def numpy_and_set_rng_state_refuse_a_gpu_tensor():
    raises(TypeError, lambda: np.asarray(gpu(2)))
    raises(TypeError, lambda: gpu(2).numpy())
    state = torch.get_rng_state()
    raises(TypeError, lambda: torch.set_rng_state(state.to("cuda")))
    raises(TypeError, lambda: torch.cuda.set_rng_state(state.to("cuda")))
    torch.set_rng_state(state)


@rule
def where_with_a_python_scalar_is_allowed():
    x = gpu(3)
    assert torch.where(x > 0, x, 0.0).is_cuda


@rule
def foreach_kernels_check_each_element():
    a, b = [gpu(2), torch.ones(2)], [gpu(2), torch.ones(2)]
    torch._foreach_add_(a, b)  # each element on one device: fine
    raises(RuntimeError, lambda: torch._foreach_add_(a, [torch.ones(2), gpu(2)]))
    assert torch._foreach_norm([gpu(2)])[0].is_cuda


@rule
def moves_copies_backward_and_capturable_adam_keep_the_device():
    lin = torch.nn.Linear(2, 1).to("cuda")
    assert copy.deepcopy(lin).weight.is_cuda and copy.deepcopy(gpu(2)).is_cuda
    opt = torch.optim.Adam(lin.parameters(), capturable=True)
    lin(gpu(2)).sum().backward()
    assert lin.weight.grad.is_cuda
    torch.nn.utils.clip_grad_norm_(lin.parameters(), 1.0, foreach=True)
    opt.step()
    assert all(v.is_cuda for v in opt.state[lin.weight].values())
    assert gpu(2).cpu().device.type == "cpu" and not gpu(2).cpu().is_cuda
    assert torch.ones(2).cuda().is_cuda and torch.ones(2).to(gpu(1)).is_cuda


@rule
def the_cpu_and_gpu_groups_of_a_foreach_kernel_are_apart():
    from torch.utils._foreach_utils import _group_tensors_by_device_and_dtype

    groups = _group_tensors_by_device_and_dtype([[gpu(2), torch.ones(2)]])
    assert {d.type for d, _ in groups} == {"cuda", "cpu"}


@rule
def a_capture_refuses_host_reads_masks_nonzero_copies_and_sync():
    x = gpu(4)
    for bad in (
        lambda: int(x.max()),
        lambda: x[x > 0],
        lambda: x.nonzero(),
        lambda: x.cpu(),
        lambda: torch.ones(4).to("cuda"),
        torch.cuda.synchronize,
        lambda: x.tolist(),
        lambda: torch.randn(2, device="cuda", generator=torch.Generator()),
    ):
        with torch.cuda.graph(torch.cuda.CUDAGraph()):
            raises(RuntimeError, bad)


@rule
def a_capture_may_draw_from_the_default_generator_and_replays_new_draws():
    g, out = torch.cuda.CUDAGraph(), gpu(64)
    with torch.cuda.graph(g):
        out.copy_(torch.randn(64, device="cuda"))
    g.replay()
    first = out.clone()
    g.replay()
    assert not torch.equal(first, out)


@rule
def a_capture_runs_no_kernel_and_replay_runs_the_recorded_ones():
    w, x, g = torch.zeros(3, device="cuda"), gpu(3), torch.cuda.CUDAGraph()
    with torch.cuda.graph(g):
        w.add_(x)
        y = w * 2
    assert w.cpu().tolist() == [0.0, 0.0, 0.0]
    g.replay()
    g.replay()
    assert w.cpu().tolist() == [2.0, 2.0, 2.0] and y.cpu().tolist() == [4.0, 4.0, 4.0]


@rule
def a_captured_cpu_scalar_is_frozen_with_a_warning():
    s, w, g = torch.tensor(1.0), torch.zeros(1, device="cuda"), torch.cuda.CUDAGraph()
    with warnings.catch_warnings(record=True) as caught, torch.cuda.graph(g):
        warnings.simplefilter("always")
        w.add_(s)
    assert any("CPU scalar" in str(c.message) for c in caught)
    s.fill_(5.0)
    g.replay()
    assert w.cpu().item() == 1.0


@rule
def capturable_adam_captures_and_a_non_capturable_one_is_refused():
    lin = torch.nn.Linear(2, 1).to("cuda")
    for capturable, ok in ((True, True), (False, False)):
        opt = torch.optim.Adam(lin.parameters(), capturable=capturable)
        lin(gpu(2)).sum().backward()
        opt.step()  # warm-up
        lin(gpu(2)).sum().backward()
        with torch.cuda.graph(torch.cuda.CUDAGraph()):
            if ok:
                opt.step()
            else:
                raises(RuntimeError, opt.step)
        opt.zero_grad()


@rule
def one_hot_reads_its_range_on_the_host_even_in_a_capture():
    idx = torch.tensor([0, 2], device="cuda")
    with torch.cuda.graph(torch.cuda.CUDAGraph()):
        assert torch.nn.functional.one_hot(idx, 3).is_cuda


@rule
def checkpoints_keep_devices_and_map_location_moves_them():
    buf = io.BytesIO()
    torch.save({"g": gpu(2), "c": torch.ones(2)}, buf)
    buf.seek(0)
    back = torch.load(buf)
    assert back["g"].is_cuda and not back["c"].is_cuda
    buf.seek(0)
    assert torch.load(buf, map_location="cuda")["c"].is_cuda
    buf.seek(0)
    assert not torch.load(buf, map_location="cpu")["g"].is_cuda


@rule
def entry_points_say_there_is_one_gpu():
    assert torch.cuda.is_available() and torch.cuda.device_count() == 1
    assert torch.accelerator.current_accelerator().type == "cuda"
    assert not torch.cuda.is_current_stream_capturing()
    with torch.autocast("cuda", dtype=torch.bfloat16):
        assert (gpu(2, 2) @ gpu(2, 2)).dtype == torch.bfloat16


@rule
def vmap_and_tensordict_keep_the_device():
    from tensordict import TensorDict

    out = torch.vmap(lambda a, b: a * b)(gpu(3, 2), gpu(3, 2))
    assert out.is_cuda
    td = TensorDict({"a": torch.ones(2)}, batch_size=[2]).to("cuda")
    assert td["a"].is_cuda and td.device.type == "cuda"


def _run(name: str) -> None:
    with emulate():
        RULES[name]()


@pytest.mark.parametrize("name", list(RULES))
def test_emulated_cuda_rule(name):
    _run(name)


_verdict: dict[str, str | None] = {}


def require_self_test(request) -> None:
    """Check every rule once per session (stop the gpu tests loudly when one fails)."""
    if "failed" not in _verdict:
        failed = []
        for name in RULES:
            try:
                _run(name)
            except (AssertionError, RuntimeError, TypeError, EmulationError) as e:
                failed.append(f"{name}: {type(e).__name__}: {e}")
        _verdict["failed"] = "; ".join(failed) or None
    if _verdict["failed"]:
        pytest.fail(
            "the CUDA emulation no longer follows CUDA's rules (a torch upgrade?): "
            + _verdict["failed"],
            pytrace=False,
        )


def test_emulation_leaves_torch_as_it_found_it():
    before = torch.cuda.is_available()
    with emulate():
        x = gpu(2)
    assert torch.cuda.is_available() == before and not on_gpu(torch.ones(1))
    assert x.device.type == "cpu"  # outside the emulation a tensor is what it really is


def test_emulation_gives_back_what_cudagraphmodule_takes_from_the_pytree():
    from tensordict import TensorDict
    from tensordict.nn import CudaGraphModule
    from torch.utils._pytree import SUPPORTED_NODES

    registered = TensorDict in SUPPORTED_NODES
    assert registered  # tensordict registers its classes in torch's pytree
    with emulate(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        CudaGraphModule(lambda td: td, in_keys=[], out_keys=[])
    assert (TensorDict in SUPPORTED_NODES) == registered
