"""The twin critics of a TD3 update in two processes: the second member in a helper process.

On a CPU with 2 cores, two threads of one process share one interpreter lock: every small
operator holds it while torch dispatches it, so two threads keep 1.3 to 1.55 times one thread's
throughput at the paper's network sizes, while two processes keep 1.9 to 2 times
(``gcnt bench-train RECIPE --processes``). :class:`InTwoProcesses` runs what
:class:`~gcnt.rl.td3.twin.AtOnce` runs on its helper thread in a helper process instead.

Both processes run the same learner code on the same mini-batch (each update's batch and
target-smoothing noise are sent to the helper when the step begins, :meth:`InTwoProcesses.step`).
At every ``map(fn, (a, b))`` of the learner the main process computes ``fn(a)`` and the helper
``fn(b)``, and the two results are swapped, so both hold ``[fn(a), fn(b)]`` and go on alike:
the target actor's halves of the batch, the target critics' Q, each critic's error and backward.
The actor's halves of the actor loss and its gradients go to the main process only
(``map(..., gather=True)``). The parameters of the four networks and the critics'
stacked gradients live in shared memory: the helper's backward writes critic 2's slice of the
gradient, which the main process clips and steps with its one fused Adam, in place, so the
helper reads the updated weights at the next step. The optimiser, the soft target update and
every random draw stay in the main process, whose random stream is the one it would be with
threads. Results cross in shared byte arenas, two per direction used in turn (:class:`Link`,
grown when a result needs more); a pipe carries their shapes.

The helper is spawned at the first step (a few seconds: it imports torch and gcnt), from the
parameters then in place; it is spawned again when they have been replaced since (a module
converted with ``.double()`` or ``.to()``). It is a daemon, ends when the main process closes its
pipe or exits, and every wait for it checks that it is alive: a helper that died or failed
during a step stops it with one line (:class:`TwinHelperError`); one found dead when a step
begins is replaced. Like any spawned process, it imports the main script again unless the script
keeps its top level under ``if __name__ == "__main__":``.
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import marshal
import math
import pickle
import signal
import time
import weakref
from collections.abc import Callable, Iterator, Sequence
from multiprocessing.reduction import ForkingPickler
from typing import Any

import torch
import torch.multiprocessing as mp
from tensordict import TensorDict, TensorDictBase

from gcnt.rl.worker_watch import WorkerDiedError

log = logging.getLogger(__name__)

#: seconds a wait polls without sleeping before it blocks: inside a step each process has a
#: core of its own, and a blocked process takes a while to be woken at each message
SPIN_S = 0.02
#: seconds between two checks that the other process is alive, while waiting for it
POLL_S = 1.0
#: views an arena keeps for the shapes it has seen (a run sees a few dozen)
MAX_VIEWS = 4096
#: byte alignment of every tensor in an arena (a view as any dtype needs its element size)
ALIGN = 64


#: signals a helper ignores (its main process handles them)
STOP_SIGNALS = tuple(
    getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGUSR2") if hasattr(signal, n)
)
#: every runner with a helper, closed at exit before multiprocessing joins its children (a
#: helper ignores the SIGTERM that multiprocessing ends daemons with)
_LIVE: weakref.WeakSet = weakref.WeakSet()


def _close_all() -> None:
    for runner in list(_LIVE):
        runner.close()


atexit.register(_close_all)


class TwinHelperError(WorkerDiedError):
    """The twin critics' helper process died or failed during a step (one line, exit 2; the
    last checkpoint is kept, and the run resumes from it)."""


class _Stop(Exception):
    """The main process asked the helper to end."""


class Arena:
    """One shared byte buffer that one process writes results into and the other reads."""

    def __init__(self, nbytes: int) -> None:
        self.buf = torch.empty(max(nbytes, ALIGN), dtype=torch.uint8).share_memory_()
        self._views: dict[tuple, torch.Tensor] = {}  # the same shapes come at every step

    def __getstate__(self) -> dict:
        return {"buf": self.buf}

    def __setstate__(self, state: dict) -> None:
        self.buf, self._views = state["buf"], {}

    def write(self, tensors: Sequence[torch.Tensor]) -> tuple[list[tuple], Arena | None]:
        """Copy ``tensors`` in (into a new, larger arena where they do not fit: returned, to be
        sent along); each tensor's (dtype, shape, offset)."""
        metas, end = [], 0
        for t in tensors:
            metas.append((t.dtype, tuple(t.shape), end))
            end += -(-t.numel() * t.element_size() // ALIGN) * ALIGN
        grown = None
        if end > self.buf.numel():
            grown = Arena(max(end, 2 * self.buf.numel()))
            self.buf, self._views = grown.buf, {}
        if tensors:
            with torch.no_grad():
                torch._foreach_copy_([self._view(*m) for m in metas], list(tensors))
        return metas, grown

    def read(self, metas: Sequence[tuple], copy: bool = True) -> list[torch.Tensor]:
        """The tensors :meth:`write` put in: copies, or (``copy=False``) views of the arena,
        which the writer overwrites two messages later."""
        views = [self._view(*m) for m in metas]
        return [v.clone() for v in views] if copy else views

    def _view(self, dtype: torch.dtype, shape: tuple, off: int) -> torch.Tensor:
        key = (dtype, shape, off)
        view = self._views.get(key)
        if view is None:
            if len(self._views) >= MAX_VIEWS:
                self._views.clear()
            n = math.prod(shape) * dtype.itemsize
            view = self._views[key] = self.buf[off : off + n].view(dtype).view(shape)
        return view


_DTYPES = {str(d): d for d in vars(torch).values() if isinstance(d, torch.dtype)}


def _named(meta: tuple) -> tuple:
    dtype, shape, off = meta
    return str(dtype), shape, off


def _typed(meta: tuple) -> tuple:
    name, shape, off = meta
    return _DTYPES[name], tuple(shape), off


def _flatten(obj: Any, leaves: list[torch.Tensor]) -> Any:
    """``obj``'s structure with each tensor replaced by its index in ``leaves``."""
    if isinstance(obj, torch.Tensor):
        leaves.append(obj.detach())
        return ("t", len(leaves) - 1)
    if isinstance(obj, TensorDictBase):
        return ("td", _flatten(obj.to_dict(), leaves), tuple(obj.batch_size))
    if isinstance(obj, (tuple, list)):
        return (type(obj).__name__, [_flatten(x, leaves) for x in obj])
    if isinstance(obj, dict):
        return ("dict", {k: _flatten(v, leaves) for k, v in obj.items()})
    return ("v", obj)


def _unflatten(spec: Any, leaves: list[torch.Tensor]) -> Any:
    kind = spec[0]
    if kind == "t":
        return leaves[spec[1]]
    if kind == "td":
        return TensorDict(_unflatten(spec[1], leaves), batch_size=spec[2])
    if kind in ("tuple", "list"):
        items = [_unflatten(x, leaves) for x in spec[1]]
        return tuple(items) if kind == "tuple" else items
    if kind == "dict":
        return {k: _unflatten(v, leaves) for k, v in spec[1].items()}
    return spec[1]


class Link:
    """One end of the pipe between the two processes, with the arenas this end writes and
    those it reads. ``alive``: whether the other process still runs (checked while waiting).

    Two arenas per direction, used in turn: a message may still be unread when its writer
    writes the next one, but not two messages later, as each side answers every message
    before the other writes again (a step's start and its first swap are the only two in a
    row, and the helper answers the start before the main process writes its third)."""

    def __init__(self, conn, mine: list[Arena], theirs: list[Arena], alive) -> None:
        self.conn, self.mine, self.theirs, self.alive = conn, mine, theirs, alive
        self.sent = 0

    def send(self, obj: Any) -> None:
        leaves: list[torch.Tensor] = []
        spec = _flatten(obj, leaves)
        slot = self.sent % 2
        self.sent += 1
        metas, grown = self.mine[slot].write(leaves)
        self._post("ok", spec, (slot, metas), grown)

    def fail(self, text: str) -> None:
        with contextlib.suppress(OSError):
            self._post("error", text)

    def _post(self, kind: str, spec: Any, where: Any = None, grown: Arena | None = None) -> None:
        """One message: marshalled (a few microseconds; dtypes by name) unless it carries a new
        arena, whose shared memory only torch's pickling can pass."""
        if grown is None:
            with contextlib.suppress(ValueError):  # a value marshal cannot write: pickled
                named = None if where is None else (where[0], [_named(m) for m in where[1]])
                self.conn.send_bytes(b"M" + marshal.dumps((kind, spec, named)))
                return
        self.conn.send_bytes(b"P" + ForkingPickler.dumps((kind, spec, where, grown)))

    def _take(self) -> tuple:
        data = self.conn.recv_bytes()
        if data[:1] == b"M":
            kind, spec, named = marshal.loads(data[1:])
            where = None if named is None else (named[0], [_typed(m) for m in named[1]])
            return kind, spec, where, None
        return pickle.loads(data[1:])

    def recv(self, copy: bool = True) -> Any:
        """The other process's next message (``copy=False``: its tensors as views of the
        arena, valid until the other's next message but one)."""
        spin_until = time.perf_counter() + SPIN_S
        while not self.conn.poll(0) and time.perf_counter() < spin_until:
            pass
        while not self.conn.poll(POLL_S):
            if not self.alive():
                raise TwinHelperError(
                    "the TD3 twin critics' helper process (compile.twin_processes) ended during "
                    "an update (killed: the OOM killer, kill -9?); the last checkpoint is kept"
                )
        kind, spec, where, grown = self._take()
        if kind == "stop":
            raise _Stop
        if kind == "error":
            raise TwinHelperError(
                f"the TD3 twin critics' helper process (compile.twin_processes) failed: {spec}"
            )
        slot, metas = where
        if grown is not None:
            self.theirs[slot] = grown
        return _unflatten(spec, self.theirs[slot].read(metas, copy))

    def swap(self, obj: Any) -> Any:
        self.send(obj)
        return self.recv()


class InTwoProcesses:
    """``map(fn, (a, b))``: ``fn(a)`` in this process and ``fn(b)`` in the helper, inside a
    :meth:`step`; outside one, both here in turn (the same values)."""

    parallel = True

    def __init__(self, rank: int = 0, link: Link | None = None) -> None:
        self.rank = rank
        self._link = link
        self._proc = None
        self._shared: list[torch.Tensor] = []
        self._ptrs: list[int] = []
        self._open = rank == 1  # the helper's side: every map is a step's

    @contextlib.contextmanager
    def step(self, learner, kind: str, *args: Any) -> Iterator[None]:
        """The helper runs ``kind`` (``"critic"``: ``critic_loss(*args, backward=True)``;
        ``"actor"``: ``_actor_grads(*args)``) while this process runs the same inside."""
        self._ready(learner)
        self._link.send((kind, args))
        self._open = True
        try:
            yield
            self._link.recv()  # the helper's "done": its gradients are written
        except BaseException:
            self.close()  # the two processes may be out of step: start anew next time
            raise
        finally:
            self._open = False

    def map(
        self, fn: Callable[[Any], Any], items: Sequence[Any], gather: bool = False
    ) -> list[Any] | None:
        """``gather``: the results go to the main process only (the helper gets None), which
        reads the helper's in place in the arena: they hold until the helper's next message
        but one, so they are to be used before the step ends."""
        if not self._open:
            return [fn(x) for x in items]
        mine = fn(items[self.rank])
        if gather and self.rank == 1:
            self._link.send(mine)
            return None
        if gather:
            return [mine, self._link.recv(copy=False)]
        theirs = self._link.swap(mine)
        return [mine, theirs] if self.rank == 0 else [theirs, mine]

    def _ready(self, learner) -> None:
        """Spawn the helper unless one runs on the parameters now in place."""
        if self._proc is not None and self._proc.is_alive():
            if all(t.data_ptr() == p for t, p in zip(self._shared, self._ptrs, strict=True)):
                return
        self.close()
        if torch.get_num_threads() != 1:
            log.info(
                "TD3 twin critics in two processes (compile.twin_processes): torch intra-op "
                "threads %d -> 1",
                torch.get_num_threads(),
            )
            torch.set_num_threads(1)
        learner.critics.prepare_grads()
        shell = learner.process_shell()
        grads = [p.grad for p in learner.critic_params]
        shared = [*shell.shared_tensors(), *grads]
        for t in shared:
            t.share_memory_()
        ctx = mp.get_context("spawn")
        here, there = ctx.Pipe()
        proc = ctx.Process(target=_serve, args=(there,), name="gcnt-twin", daemon=True)
        proc.start()
        there.close()
        mine, theirs = [Arena(1 << 20) for _ in range(2)], [Arena(1 << 20) for _ in range(2)]
        self._link = Link(here, mine, theirs, proc.is_alive)
        self._proc, self._shared = proc, shared
        _LIVE.add(self)
        self._ptrs = [t.data_ptr() for t in shared]
        # the recipe first: unpickling it imports its plugins, whose networks the shell holds
        here.send((learner.recipe, shell, grads, theirs, mine))
        self._link.recv()  # "ready"

    def close(self) -> None:
        """End the helper (if any) and forget it."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        with contextlib.suppress(OSError):
            self._link._post("stop", None)
            self._link.conn.close()
        proc.join(5)
        if proc.is_alive():
            proc.kill()
            proc.join()

    def __getstate__(self) -> dict:  # copies (loss shells, pickles) start without a helper
        return {"rank": 0, "_link": None, "_proc": None, "_shared": [], "_ptrs": [], "_open": False}

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()


def _serve(conn) -> None:
    """The helper process: build the shell sent, then run each step the main process begins
    until it sends "stop" or closes the pipe."""
    import os

    # the main process decides when a run stops (gcnt.rl.stop: Ctrl-C reaches the whole process
    # group, Slurm signals every process of a job step); the helper ends with it: a "stop"
    # message, its pipe closed, or its parent gone
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    torch.set_num_threads(1)
    parent = os.getppid()
    try:
        recipe, shell, grads, mine, theirs = conn.recv()
        del recipe
        for p, g in zip(shell.critic_params, grads, strict=True):
            p.grad = g
        link = Link(conn, mine, theirs, lambda: os.getppid() == parent)
        shell.twin = InTwoProcesses(rank=1, link=link)
        link.send("ready")
    except Exception as e:  # noqa: BLE001 - sent to the main process, which raises it
        Link(conn, [], [], lambda: True).fail(f"{type(e).__name__}: {e}")
        return
    while True:
        try:
            what, args = link.recv()
            if what not in STEPS:
                raise ValueError(f"no step {what!r}")
            STEPS[what](shell, *args)
            link.send("done")
        except (_Stop, EOFError, OSError, TwinHelperError):
            return
        except Exception as e:  # noqa: BLE001 - sent to the main process, which raises it
            link.fail(f"{type(e).__name__}: {e}")
            return


def _critic_grads(learner, batch: TensorDictBase, noise: torch.Tensor) -> None:
    learner.critic_loss(batch, noise, backward=True)


def _actor_grads(learner, batch: TensorDictBase) -> None:
    learner._actor_grads(batch)


#: what the helper runs for each kind of step the main process begins
STEPS = {"critic": _critic_grads, "actor": _actor_grads}
