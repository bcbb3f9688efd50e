"""The twin critics of a TD3 update, one after the other or on two threads at once.

TD3's two critics (and its two target critics) are one ensemble of stacked parameters
(:class:`~gcnt.rl.td3.ensemble.Ensemble`): the same calls on the same batch with different
weights. On a GPU, or compiled, the ensemble runs in one vmapped call (half the kernels of two
networks). On a CPU with a few cores the quick start's update is bound by its arithmetic more
than by its operator count (it took 7.3 ms at 1 sample per robot and 23 ms at 128, on one core),
and vmap's batched linear layers cost more arithmetic passes than two plain ones, so there each
member runs on its own thread, one core each: torch releases the GIL inside its kernels, and the
autograd engine runs ``backward`` calls of disjoint graphs from two threads concurrently. Each
member's operations are those of a network of its own, in the same order as in turn; the
gradients of both land in the stacked parameters' one gradient (each member's slice of it).

:class:`InTurn` and :class:`AtOnce` share one method, ``map(fn, (a, b)) -> [fn(a), fn(b)]``;
:func:`make_pair_runner` picks one for a recipe's ``compile.twin_threads``, or, with
``compile.twin_processes``, :class:`~gcnt.rl.td3.twin_process.InTwoProcesses`: the second member
in a helper process, which two threads' shared interpreter lock does not slow.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import torch

from gcnt.envs.stepper import usable_cpus
from gcnt.rl.td3.twin_process import InTwoProcesses

log = logging.getLogger(__name__)


class InTurn:
    """``fn`` on each item, one after the other."""

    parallel = False

    def step(self, learner: Any, kind: str, *args: Any) -> contextlib.AbstractContextManager:
        """Where a step's ``map`` calls run (a helper process is told what the step computes,
        :class:`~gcnt.rl.td3.twin_process.InTwoProcesses`); here, nothing to tell."""
        return contextlib.nullcontext()

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any], gather: bool = False) -> list:
        """``[fn(x) for x in items]``; ``gather``: only the calling process needs the results
        (one of two processes gets None, :mod:`~gcnt.rl.td3.twin_process`)."""
        return [fn(x) for x in items]


class EachInTurn(InTurn):
    """What :class:`AtOnce` does (each member its own call and backward), one after the other on
    the calling thread: the same operators, where a profiler of that thread sees them all."""

    parallel = True


class AtOnce:
    """``fn`` on two items at once: the second on a helper thread, the first on the caller's.

    The helper inherits the caller's grad mode (torch's grad mode is per thread). At the first
    call torch's intra-op threads are set to 1 for the process (logged): the two threads already
    use two cores, and torch's OpenMP threads are what makes a CPU update several times slower
    when another job shares the cores (each small kernel's parallel region waits for a thread
    the other job has taken: the quick start's critic step 32 ms on one thread, 185 ms on two,
    beside a busy loop on a 2-core machine)."""

    parallel = True
    step = InTurn.step

    def __init__(self) -> None:
        self._pool: ThreadPoolExecutor | None = None
        self._pid = os.getpid()

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any], gather: bool = False) -> list:
        first, second = items
        if self._pid != os.getpid():  # a forked child: the parent's helper thread is not here
            self._pool, self._pid = None, os.getpid()
        if self._pool is None:
            if torch.get_num_threads() != 1:
                log.info(
                    "TD3 twin critics on two threads (compile.twin_threads): torch intra-op "
                    "threads %d -> 1",
                    torch.get_num_threads(),
                )
                torch.set_num_threads(1)
            self._pool = ThreadPoolExecutor(
                1, thread_name_prefix="gcnt-twin", initializer=torch.set_num_threads, initargs=(1,)
            )
        grad = torch.is_grad_enabled()

        def helper() -> Any:
            with torch.set_grad_enabled(grad):
                return fn(second)

        future = self._pool.submit(helper)
        try:
            out = fn(first)
        finally:
            other = future.result()  # waited for even when fn(first) failed
        return [out, other]

    def __getstate__(self) -> dict:  # copies (loss shells, pickles) start without a pool
        return {"_pool": None, "_pid": os.getpid()}


def make_pair_runner(
    setting: bool | None,
    device: torch.device,
    compiled: bool,
    dropout: bool,
    torch_threads: int | None = None,
    processes: bool = False,
) -> InTurn | AtOnce | InTwoProcesses:
    """``compile.twin_threads``: True -> :class:`AtOnce`, False -> :class:`InTurn`; None (auto)
    -> :class:`AtOnce` when the update runs eagerly on a CPU with 2 to 4 usable cores, the
    critics have no active dropout and ``compile.torch_threads`` is unset or 1 (with more cores,
    or more intra-op threads asked for, torch's own threads are left to use them).
    ``processes`` (``compile.twin_processes``): where the members run at once, they run in two
    processes (:class:`~gcnt.rl.td3.twin_process.InTwoProcesses`) instead of two threads.

    Dropout draws from torch's one global generator, and two threads would draw in an order
    that changes from run to run (a seeded run would not repeat), so ``True`` with dropout is
    refused."""
    if setting and dropout:
        raise ValueError(
            "compile.twin_threads=true: the critics have dropout, whose random draws two threads "
            "would make in a varying order (a seeded run would not repeat); set it to false or "
            "leave it unset"
        )
    if setting is None:
        setting = (
            device.type == "cpu"
            and not compiled
            and not dropout
            and (torch_threads or 1) == 1
            and 2 <= usable_cpus() <= 4
        )
    if not setting:
        return InTurn()
    return InTwoProcesses() if processes and device.type == "cpu" else AtOnce()
