"""Range checks shared by the algorithm recipe sections (``td3:``, ``ppo:``).

Imported by the recipe loader without torch, so keep this module free of heavy imports (the
memory checks import what they need when called).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

#: rule -> (whether a value breaks it, what the error says the value must be)
_RULES = {
    ">= 1": (lambda v: v < 1, "must be >= 1"),
    ">= 0": (lambda v: v < 0, "must be >= 0"),
    "positive finite": (
        lambda v: not (v > 0 and math.isfinite(v)),
        "must be a positive finite number",
    ),
    "[0, 1]": (lambda v: not 0.0 <= v <= 1.0, "must be in [0, 1]"),
    ">= 0 finite": (lambda v: not (v >= 0 and math.isfinite(v)), "must be >= 0 and finite"),
}


def check_range(config: object, rule: str, *keys: str) -> None:
    """A ValueError naming the first of ``keys`` (attributes of ``config``) that breaks
    ``rule`` (one of ``_RULES``)."""
    breaks, what = _RULES[rule]
    for key in keys:
        v = getattr(config, key)
        if breaks(v):
            raise ValueError(f"{key} {what}, got {v}")


def memory_bytes(device: str = "cpu") -> int | None:
    """The memory a run can use on ``device``: a CUDA device's total memory, else the
    machine's physical memory, or the cgroup's limit or the process's address-space limit
    (``ulimit -v``, RLIMIT_AS) where that is lower (a Slurm job, a container, a shell limit);
    None where it cannot be read."""
    found = memory_limit(device)
    return None if found is None else found[0]


def memory_limit(device: str = "cpu") -> tuple[int, str] | None:
    """:func:`memory_bytes` and what sets it (``the memory of this machine``, ``this
    process's address-space limit (ulimit -v) ...``), to say so when a run would not fit."""
    if str(device).startswith("cuda"):
        import torch

        total = int(torch.cuda.get_device_properties(torch.device(device)).total_memory)
        return total, f"the memory of {device}"
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):  # not a POSIX system
        return None
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
    except OSError:
        limit = "max"
    have, what = total, "the memory of this machine"
    if limit.isdigit() and int(limit) < total:
        have, what = int(limit), "this job's memory limit (its cgroup's memory.max)"
    try:
        import resource

        soft, unlimited = resource.getrlimit(resource.RLIMIT_AS)[0], resource.RLIM_INFINITY
    except (ImportError, OSError, ValueError):  # not a POSIX system
        return have, what
    if soft == unlimited or soft <= 0:
        return have, what
    # the limit counts the address space already mapped (torch and its libraries: GBs)
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[0])
        mapped = pages * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        mapped = 0
    free = max(0, soft - mapped)
    if free < have:
        return free, (
            f"what this process's address-space limit (ulimit -v, {_bytes(soft)}) leaves "
            f"beside the {_bytes(mapped)} it has mapped"
        )
    return have, what


def check_memory(nbytes: int, device: str, what: str, fix: str) -> None:
    """A RecipeError before anything runs when ``what`` needs ``nbytes`` bytes, more than
    :func:`memory_bytes` of ``device`` (it could never fit); ``fix``: which setting to lower."""
    from gcnt.recipes import RecipeError

    found = memory_limit(device)
    if found is not None and nbytes > found[0]:
        have, where = found
        raise RecipeError(
            f"{what} would take {_bytes(nbytes)}, more than {_bytes(have)}: {where}; {fix}"
        )


def check_replay_memory(env, num_robots: int, capacity: int, device: str) -> None:
    """The TD3 replay's storage (``num_robots`` x ``capacity`` transitions of ``env``'s
    stored keys, allocated at its first batch) checked against :func:`memory_bytes`."""
    from gcnt.rl.td3.replay import OPTIONAL_KEYS, STORED_KEYS

    one = env.fake_tensordict().reshape(-1)[0]
    present = set(one.keys(True, True))
    per = sum(
        one.get(k).numel() * one.get(k).element_size()
        for k in (*STORED_KEYS, *OPTIONAL_KEYS)
        if k in present
    )
    check_memory(
        num_robots * capacity * per,
        device,
        f"the replay ({num_robots} robots x {capacity} transitions x {per} bytes)",
        "lower td3.buffer_size_per_robot or td3.buffer_total_size",
    )


def _bytes(n: float) -> str:
    """``n`` bytes in decimal units (``24.0 TB``)."""
    if n < 1000:
        return f"{int(n)} B"
    for unit in ("KB", "MB", "GB"):
        n /= 1000
        if n < 1000:
            return f"{n:.1f} {unit}"
    return f"{n / 1000:.1f} TB"
