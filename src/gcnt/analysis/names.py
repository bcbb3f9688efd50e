"""Display names: what figures and tables call methods, tasks and robot sets.

Run directories name a method by its registry id (``metamorph_star``), a task by the recipe's
``task`` (``Walker++``; its folder spells it ``Walkerpp``, a sweep's ``walkerpp``) and a robot set
by what was evaluated (a label, a robot spec, or a pattern such as ``walker_*``). Figures and
tables show :data:`METHOD_NAMES` and :data:`TASK_NAMES` instead, and a command's ``--names
KEY=NAME`` overrides either.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from gcnt.suggest import did_you_mean

#: registry id -> the name the paper uses (every id of :data:`gcnt.nn.registry.NETWORKS`)
METHOD_NAMES: dict[str, str] = {
    "gcnt": "GCNT",
    "gcnt_no_gcn": "GCNT w/o GCN",
    "gcnt_no_wl": "GCNT w/o WL",
    "gcnt_no_dist": "GCNT w/o distance bias",
    "gcnt_dist_first": "GCNT (distance bias in layer 1)",
    "gcnt_gcn_context": "GCNT (GCN on the limb context)",
    "gcnt_hn": "GCNT+HN",
    "amorpheus": "AMORPHEUS",
    "swat": "SWAT",
    "smp": "SMP",
    "metamorph": "MetaMorph",
    "metamorph_star": "MetaMorph*",
    "modumorph": "ModuMorph",
    "sr": "SR",
    "mlp": "MLP",
}

#: the task ids of the shipped recipes (``recipes/*/*.yaml``)
TASKS = (
    "Walker++",
    "Cheetah++",
    "Humanoid++",
    "Hopper++",
    "CWHH++",
    "UNIMAL-FT",
    "UNIMAL-MT",
    "UNIMAL-Incline",
    "UNIMAL-Obstacles",
    "UNIMAL100-FT",
    "study-Walker++",
    "study4-Walker++",
    "study5-Walker++",
    "study-UNIMAL-FT",
    "study-UNIMAL-FT-fair",
    "study-UNIMAL100-FT-fair",
)


def _folder_spellings(task: str) -> tuple[str, str]:
    """How a task is spelt as a run folder (``Walkerpp``) and as a sweep folder (``walkerpp``)."""
    run = "".join(c if c.isalnum() or c in "-_" else "-" for c in task.replace("+", "p"))
    sweep = re.sub(r"[^a-z0-9._-]+", "-", task.replace("+", "p").lower()).strip("-")
    return run, sweep


#: a task's folder spellings -> the task
TASK_NAMES: dict[str, str] = {
    spelt: task for task in TASKS for spelt in _folder_spellings(task) if spelt != task
}


def display_name(key: str, names: Mapping[str, str] | None = None) -> str:
    """What figures and tables call ``key`` (a method id or label, a task): ``names[key]``, else
    the default tables; an algorithm-prefixed label (``ppo:gcnt``, runs of mixed algorithms) is
    the method's name with the algorithm after it (``GCNT (PPO)``), and a label that adds to a
    method (``gcnt [td3.lr=0.001]``: one of several experiments) keeps its addition after the
    method's name; anything else as it is."""
    names = names or {}
    if key in names:
        return names[key]
    if key in METHOD_NAMES:
        return METHOD_NAMES[key]
    if key in TASK_NAMES:
        return TASK_NAMES[key]
    head, space, rest = key.partition(" ")
    if space and head and display_name(head, names) != head:
        return f"{display_name(head, names)} {rest}"
    algo, sep, method = key.partition(":")
    if sep and algo in ("td3", "ppo") and method and " " not in algo:
        return f"{display_name(method, names)} ({algo.upper()})"
    return key


def is_pattern(name: str) -> bool:
    """A robot name pattern (``walker_*``, ``unimal_000?``) rather than a name or a spec."""
    return any(c in name for c in "*?[") and ":" not in name


def set_display_name(
    name: str, robots: Sequence[str], names: Mapping[str, str] | None = None
) -> str:
    """What a figure calls robot set ``name``: ``names[name]``, else the name, except that a
    pattern is never shown: the robots it resolved to are (the first two and the last)."""
    names = names or {}
    if name in names:
        return names[name]
    if not is_pattern(name):
        return name
    robots = list(dict.fromkeys(robots))
    if not robots:
        return "no robots"
    if len(robots) <= 3:
        return ", ".join(robots)
    return f"{robots[0]}, {robots[1]}, …, {robots[-1]}"


def run_keys(runs: Iterable[Any]) -> set[str]:
    """The methods, labels and tasks of ``runs`` (:class:`gcnt.analysis.runs.Run`): what
    ``--names`` can name in their figures and tables (see :func:`unknown_names`)."""
    return {key for r in runs for key in (r.method, r.label, r.task)}


def unknown_names(given: Iterable[str], shown: Iterable[str], *, any_known: bool = False) -> str:
    """The first key of ``given`` that names nothing ``shown`` (a method, task or robot set of
    this figure or table; also spelt as a folder, ``Walkerpp``, prefixed by an algorithm,
    ``ppo:gcnt``, or with an addition, ``gcnt [td3.lr=0.001]``), as an error message with the
    closest keys; "" if each names something. ``any_known``: a key of the default tables
    (:data:`METHOD_NAMES`, the shipped tasks) passes too (a names file shared by figures)."""
    shown = set(shown)
    known = shown | (set(METHOD_NAMES) | set(TASKS) if any_known else set())
    spelt = known | {s for key in known for s in _folder_spellings(key)}
    for key in given:
        base = key.split(" [", 1)[0]
        if base in spelt or base.partition(":")[2] in spelt:
            continue
        listed = ", ".join(sorted(shown)) or "none"
        return (
            f"--names {key}: no method, task or robot set here is called {key!r}"
            f"{did_you_mean(key, known, ignore_case=True)} (names here: {listed})"
        )
    return ""
