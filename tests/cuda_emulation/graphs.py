"""``torch.cuda.CUDAGraph`` / ``torch.cuda.graph`` on the emulated GPU, and the stream and event
objects around them. A capture runs the captured code once, raising where a real capture fails
(:mod:`.rules`), records its GPU ops and then undoes what they wrote to older memory (a real
capture runs no kernel); ``replay()`` re-executes exactly the recorded ops on the same tensors.
Python side effects are not replayed, as on a GPU."""

from __future__ import annotations

import torch

from . import rules, state
from .state import CUDA, EmulationError

#: captures ended and replays run, over the process (tests check that a graphed path replays)
counts = {"captures": 0, "replays": 0}


class CUDAGraph:
    def __init__(self, keep_graph: bool = False) -> None:
        self._ops: list | None = None
        self._capture: state.Capture | None = None

    def capture_begin(self, pool=None, capture_error_mode: str = "global") -> None:
        if state.capture[0] is not None:
            raise EmulationError("a CUDA graph capture is already in progress")
        self._capture = state.Capture(self)
        state.capture[0] = self._capture

    def capture_end(self) -> None:
        cap, state.capture[0] = self._capture, None
        cap.roll_back()
        self._ops = cap.ops
        self._capture = None
        counts["captures"] += 1

    def replay(self) -> None:
        if self._ops is None:
            raise EmulationError("CUDAGraph.replay() before a capture")
        if state.capture[0] is not None:
            raise EmulationError("CUDAGraph.replay() inside a capture")
        rules.replay(self._ops)
        counts["replays"] += 1

    def reset(self) -> None:
        self._ops = None

    def pool(self):
        return (0, id(self))

    def instantiate(self) -> None:
        pass

    def enable_debug_mode(self) -> None:
        pass

    @property
    def num_ops(self) -> int:
        return len(self._ops or ())


class graph:  # noqa: N801 (torch's name)
    """``with torch.cuda.graph(g): ...``: capture into ``g``."""

    default_capture_stream = None

    def __init__(self, cuda_graph: CUDAGraph, pool=None, stream=None,
                 capture_error_mode: str = "global") -> None:  # fmt: skip
        self.cuda_graph = cuda_graph

    def __enter__(self) -> None:
        torch.cuda.synchronize()
        self.cuda_graph.capture_begin()

    def __exit__(self, *exc) -> bool:
        if state.capture[0] is not None and state.capture[0].graph is self.cuda_graph:
            self.cuda_graph.capture_end()
        return False


def graph_pool_handle():
    return (0, 0)


def is_current_stream_capturing() -> bool:
    return state.capture[0] is not None


def synchronize(device=None) -> None:
    if state.capture[0] is not None:
        raise EmulationError(
            "CUDA error: operation not permitted when stream is capturing (synchronize)"
        )


class Stream:
    """One stream: work is in order anyway on the emulated GPU."""

    def __new__(cls, device=None, priority: int = 0, **kwargs):
        return super().__new__(cls)

    def __init__(self, device=None, priority: int = 0, **kwargs) -> None:
        self.device = CUDA
        self.device_index = 0
        self.device_type = 1
        self.cuda_stream = 0
        self.stream_id = 0

    def wait_stream(self, stream) -> None:
        pass

    def wait_event(self, event) -> None:
        pass

    def record_event(self, event=None):
        event = event or Event()
        event.record(self)
        return event

    def query(self) -> bool:
        return True

    def synchronize(self) -> None:
        synchronize()

    def is_capturing(self) -> bool:
        return is_current_stream_capturing()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> bool:
        return False

    def __eq__(self, other) -> bool:
        return isinstance(other, Stream)

    def __hash__(self) -> int:
        return 0


_STREAM = Stream()


def current_stream(device=None) -> Stream:
    return _STREAM


class _StreamContext:
    def __init__(self, stream) -> None:
        self.stream = stream

    def __enter__(self):
        return self.stream

    def __exit__(self, *exc) -> bool:
        return False


def stream(s) -> _StreamContext:
    return _StreamContext(s)


class Event:
    def __init__(self, enable_timing: bool = False, blocking: bool = False,
                 interprocess: bool = False) -> None:  # fmt: skip
        import time

        self._clock = time.perf_counter
        self._t: float | None = None

    def record(self, stream=None) -> None:
        self._t = self._clock()

    def wait(self, stream=None) -> None:
        pass

    def query(self) -> bool:
        return True

    def synchronize(self) -> None:
        synchronize()

    def elapsed_time(self, end: Event) -> float:
        return 1000.0 * (end._t - self._t)
