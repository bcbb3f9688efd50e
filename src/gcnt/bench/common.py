"""What every training benchmark reports beside its rates: the machine's matmul peak, the
update's arithmetic (FLOPs of its matrix products) and its launches (device kernels on a GPU,
dispatched operators on a CPU), and a quiet ``gcnt train`` in a temporary run directory.

A small share of the matmul peak means the update is bound by per-call overhead, not by
arithmetic; launches times a few microseconds is its floor when it is.
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
import time
from collections.abc import Iterator


def matmul_peak_gflops(
    size: int | None = None, repeats: int = 5, device: str = "cpu", amp: bool = False
) -> float:
    """GFLOP/s of the best of ``repeats`` ``size`` × ``size`` matrix products on ``device``, in
    the update's precision: float32 (on a GPU with torch's TF32 setting as configured), bfloat16
    with ``amp``. The arithmetic limit the updates are measured against. On a CPU the products
    run on torch's threads as configured (size 1024); on a GPU they are timed with CUDA events
    (size 8192, so that the product fills the device)."""
    import torch

    dev = torch.device(device)
    cuda = dev.type == "cuda"
    size = size or (8192 if cuda else 1024)
    dtype = torch.bfloat16 if amp else torch.float32
    a = torch.randn(size, size, device=dev, dtype=dtype)
    b = torch.randn(size, size, device=dev, dtype=dtype)
    torch.mm(a, b)  # warm-up
    best = float("inf")
    for _ in range(repeats):
        if cuda:
            start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
            start.record()
            torch.mm(a, b)
            end.record()
            end.synchronize()
            seconds = start.elapsed_time(end) / 1e3
        else:
            t0 = time.perf_counter()
            torch.mm(a, b)
            seconds = time.perf_counter() - t0
        best = min(best, seconds)
    return 2 * size**3 / best / 1e9


def matrix_products(fn) -> tuple[dict[tuple, int], object]:
    """The matrix products ``fn()`` dispatches (``mm``, ``addmm``, ``bmm``, ``baddbmm``: what
    linear layers and batched products become), as ``{(op, shape of a, shape of b): calls}``, and
    what ``fn`` returned. Attention kernels are left out (their products are inside one call)."""
    import torch
    from torch.utils._python_dispatch import TorchDispatchMode

    aten = torch.ops.aten
    operands = {aten.mm: (0, 1), aten.bmm: (0, 1), aten.addmm: (1, 2), aten.baddbmm: (1, 2)}
    seen: dict[tuple, int] = {}

    class Products(TorchDispatchMode):
        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            where = operands.get(func.overloadpacket)
            if where is not None:
                a, b = (args[i] for i in where)
                key = (func.overloadpacket.__name__, tuple(a.shape), tuple(b.shape))
                seen[key] = seen.get(key, 0) + 1
            return func(*args, **(kwargs or {}))

    with Products():
        out = fn()
    return seen, out


def product_flops(op: str, a: tuple, b: tuple) -> int:
    """2 × m × k × n (× batch) of one product of shapes ``a`` [.., m, k] and ``b`` [.., k, n]."""
    batch = a[0] if op in ("bmm", "baddbmm") else 1
    return 2 * batch * a[-2] * a[-1] * b[-1]


def shapes_peak_gflops(products: dict[tuple, int], repeats: int = 20, device: str = "cpu") -> dict:
    """GFLOP/s of ``products`` (:func:`matrix_products`) run alone, each shape ``repeats`` times
    on fresh float32 tensors (best of 3), weighted by how often the update calls it: the rate the
    update's own matrix shapes allow through torch's products, each call's dispatch included,
    against which the update's arithmetic rate is read. Also the share of that time in each
    product kind."""
    import torch

    dev = torch.device(device)
    total_flops, total_s = 0, 0.0
    for (op, a, b), calls in products.items():
        x, y = torch.randn(a, device=dev), torch.randn(b, device=dev)
        fn = torch.bmm if op in ("bmm", "baddbmm") else torch.mm
        fn(x, y)
        best = float("inf")
        for _ in range(3):
            t0 = time.perf_counter()
            for _ in range(repeats):
                fn(x, y)
            if dev.type == "cuda":
                torch.cuda.synchronize(dev)
            best = min(best, (time.perf_counter() - t0) / repeats)
        total_flops += calls * product_flops(op, a, b)
        total_s += calls * best
    return {
        "gflops": total_flops / total_s / 1e9 if total_s else float("nan"),
        "flops": total_flops,
        "seconds": total_s,
        "shapes": len(products),
    }


def device_line(device: str) -> str:
    """What the update runs on: the GPU's name and its peak memory so far, or the CPU threads."""
    import torch

    dev = torch.device(device)
    if dev.type == "cuda":
        name = torch.cuda.get_device_name(dev)
        mem = torch.cuda.max_memory_allocated(dev) / 2**30
        return f"device: {name}, {mem:.2f} GiB peak memory allocated"
    return f"device: CPU, {torch.get_num_threads()} torch threads"


def count_flops(fn) -> tuple[int, object]:
    """Floating-point operations of the matrix products ``fn()`` runs (torch's
    ``FlopCounterMode``: matmul, linear, batched and attention products; elementwise work is not
    counted), and what ``fn`` returned."""
    import torch
    from torch.utils import flop_counter as fc

    aten = torch.ops.aten
    # torch's counter has formulas for the GPU attention kernels only; the CPU kernel does the
    # same products
    cpu_attention = {
        aten._scaled_dot_product_flash_attention_for_cpu: lambda q, k, v, *_, **__: (
            fc.sdpa_flop_count(q, k, v)
        ),
        aten._scaled_dot_product_flash_attention_for_cpu_backward: lambda g, q, k, v, *_, **__: (
            fc.sdpa_backward_flop_count(g, q, k, v)
        ),
    }
    counter = fc.FlopCounterMode(display=False, custom_mapping=cpu_attention)
    with counter:
        out = fn()
    return counter.get_total_flops(), out


#: the lines torch's profiler (kineto) writes to the process's stderr whenever it starts and
#: stops, e.g. ``USDT:2026-01-01 10:00:00 123:123 SyncActivityProfilerHandler.cpp:52]
#: profiler_start``
PROFILER_LINE = re.compile(r"^(USDT|STAGE):\d{4}-\d\d-\d\d [\d:.]+ \d+:\d+ \w+\.cpp:\d+\] ")


@contextlib.contextmanager
def without_profiler_lines() -> Iterator[None]:
    """Keep torch's profiler lines (:data:`PROFILER_LINE`, written by C++ straight to file
    descriptor 2) out of the report: stderr goes to a temporary file meanwhile, and every other
    line written there is passed on afterwards."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as caught:
        os.dup2(caught.fileno(), 2)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            caught.seek(0)
            text = caught.read().decode(errors="replace")
            kept = [line for line in text.splitlines(True) if not PROFILER_LINE.match(line)]
            sys.stderr.write("".join(kept))
            sys.stderr.flush()


def count_launches(fn, device: str = "cpu") -> int:
    """What bounds a small update from below when its arithmetic is cheap: the calls it makes.
    On a GPU, the device kernels ``fn()`` launches (torch's profiler: events on the CUDA
    device); on a CPU, the operators it dispatches (profiled ``aten::`` ops not called from
    inside another). Each costs a few microseconds whatever its size, so ``count x a few us``
    is the update's launch floor."""
    return count_operators(fn, device)[0]


#: operators that only describe a tensor (no data written) beyond those whose schema says they
#: return a view of an input
_NO_WORK = frozenset({"detach", "t", "empty", "empty_strided", "new_empty_strided", "to"})
_COPIES = frozenset({"aten::copy_", "aten::clone", "aten::_to_copy"})


def count_operators(fn, device: str = "cpu") -> tuple[int, int]:
    """``(dispatched, working)`` for ``fn()``: on a GPU both are the device kernels it launches;
    on a CPU the operators it dispatches (:func:`count_launches`), and of them those that write
    data (a GPU's kernels): not views of their input (the operator's schema), unless they copied
    (a ``reshape`` of strided data, a ``to`` that cast)."""
    import torch
    from torch.autograd import DeviceType
    from torch.profiler import ProfilerActivity, profile

    cuda = torch.device(device).type == "cuda"
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
    with without_profiler_lines():
        with profile(activities=activities) as prof:
            fn()
            if cuda:
                torch.cuda.synchronize(device)
        events = prof.events()
    if cuda:
        kernels = sum(1 for e in events if e.device_type == DeviceType.CUDA)
        return kernels, kernels

    def nested(e) -> bool:
        parent = e.cpu_parent
        while parent is not None:
            if parent.name.startswith("aten::"):
                return True
            parent = parent.cpu_parent
        return False

    def copied(e) -> bool:
        todo = list(e.cpu_children)
        while todo:
            child = todo.pop()
            if child.name in _COPIES:
                return True
            todo.extend(child.cpu_children)
        return False

    top = [e for e in events if e.name.startswith("aten::") and not nested(e)]
    working = sum(1 for e in top if not _is_view(e.name[len("aten::") :]) or copied(e))
    return len(top), working


def _is_view(name: str) -> bool:
    if name in _NO_WORK:
        return True
    import torch

    op = getattr(torch.ops.aten, name, None)
    if op is None:
        return False
    schema = getattr(op, op.overloads()[0])._schema
    return bool(schema.returns) and all(
        r.alias_info is not None and not r.alias_info.is_write for r in schema.returns
    )


def arithmetic(flops_per_update: float, updates_per_s: float, peak: float) -> dict:
    """The arithmetic figures of an update rate: FLOPs per update, GFLOP/s, share of ``peak``."""
    gflops = flops_per_update * updates_per_s / 1e9
    return {
        "flops_per_update": flops_per_update,
        "gflops_per_s": gflops,
        "share_of_peak": gflops / peak,
    }


def arithmetic_line(a: dict, peak: float, unit: str = "update") -> str:
    return (
        f"       {a['flops_per_update'] / 1e6:,.1f} MFLOP per {unit} in matrix products: "
        f"{a['gflops_per_s']:.2f} GFLOP/s = {100 * a['share_of_peak']:.1f}% of the "
        f"{peak:.1f} GFLOP/s matmul peak"
    )


def launch_line(launches: float, update_ms: float, device: str) -> str:
    """How close an update is to its launch floor: its launches and the time per launch (a few
    microseconds per launch means the launches, not the arithmetic, set the update's time)."""
    import torch

    what = "device kernels" if torch.device(device).type == "cuda" else "dispatched operators"
    return (
        f"       {launches:,.0f} {what} per update: {1e3 * update_ms / max(launches, 1):.1f} us "
        "per launch"
    )


def train_quietly(recipe, log_interval: int) -> list[dict]:
    """Train ``recipe`` in a temporary run directory (no logger backend, progress bar,
    checkpoints or evaluation; a metrics row every ``log_interval`` steps); its metrics rows."""
    from gcnt.rl.loop import train
    from gcnt.run.directory import RunDir

    with tempfile.TemporaryDirectory() as tmp:
        recipe.run_dir = tmp
        recipe.logger.backend, recipe.logger.progress = "none", False
        recipe.logger.log_interval = log_interval
        recipe.checkpoint_interval = 10**12
        recipe.eval.episodes = 0
        run = RunDir(tmp)
        run.create(recipe)
        train(recipe, run)
        return run.read_metrics()
