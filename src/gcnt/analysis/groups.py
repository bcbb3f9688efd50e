"""Which runs are seeds of one experiment: the groups that ``gcnt curves``, ``zeroshot`` and
``variants`` aggregate over.

Runs are grouped by task, by the name their method is shown under (:func:`method_labels`) and
by :attr:`Run.fingerprint`: their resolved recipes agree on every key but the seed and the keys
that do not change the experiment (:data:`gcnt.analysis.runs.NOT_THE_EXPERIMENT`). Runs of one
task and method that are not seeds of one experiment (another budget, other robots, other
settings) are split into one group per experiment, each shown under the method's name followed
by the values of the keys that tell them apart (``gcnt [collector.total_frames=24000]``), with a
warning naming those keys and their values (``collector.total_frames: 24000 vs 12000``). Two
runs of one seed in one group (a run made twice) are refused, naming both: a seed counts once.
The per-robot runs of one seed (``gcnt sweep --per-robot``) are one seed of their group, each
robot counted once. The plugins a run was trained with are not part of its experiment (a plugin
cannot replace a built-in method): seeds of one group trained with different plugins, or with
other versions of one (another sha256: a plugin method's code changed between seeds), are pooled
with a warning naming each seed's plugins.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from gcnt.analysis.runs import AnalysisError, Run, method_key, method_labels, recipe_defaults

log = logging.getLogger(__name__)

#: the differing keys named in a split group's name (all of them are in the warning)
SHOWN_KEYS = 3
#: the longest value shown for a key (longer ones are cut, ending in ``...``)
SHOWN_VALUE = 40


@dataclass(frozen=True)
class RunGroup:
    """The runs that are seeds of one experiment, in seed order (then robot, then path)."""

    task: str
    #: the method's name (:func:`method_labels`)
    method: str
    #: the name the group is shown under: the method's, followed by the keys that tell it apart
    #: where other runs of its task and method are another experiment
    label: str
    runs: tuple[Run, ...]
    #: the runs' :attr:`Run.fingerprint`
    fingerprint: str


def comparable_groups(runs: Sequence[Run]) -> list[RunGroup]:
    """The runs as seeds of experiments (see the module's docstring), sorted by task, then
    method (:func:`method_key`), then name; an AnalysisError naming both runs where one group
    holds a seed twice."""
    labels = method_labels(runs)
    kinds: dict[tuple[str, str], dict[str, list[Run]]] = {}
    for r in runs:
        kinds.setdefault((r.task, labels[r.path]), {}).setdefault(r.fingerprint, []).append(r)
    groups = []
    for (task, method), by_print in kinds.items():
        names = _names(task, method, by_print) if len(by_print) > 1 else {}
        for fingerprint, members in by_print.items():
            members.sort(key=lambda r: (r.seed, r.single_robot or "", str(r.path)))
            label = names.get(fingerprint, method)
            _check_seeds(task, label, members)
            _warn_plugins(task, label, members)
            groups.append(RunGroup(task, method, label, tuple(members), fingerprint))
            sources = list(dict.fromkeys(s for r in members if (s := r.fine_tune_of)))
            if sources:
                more = f" and {len(sources) - 3} more" if len(sources) > 3 else ""
                log.info("%s %s: fine-tuned from %s%s", task, label, "; ".join(sources[:3]), more)
    return sorted(groups, key=lambda g: (g.task, method_key(g.method), g.label))


def differing_keys(experiments: Sequence[dict[str, Any]]) -> list[str]:
    """The dotted keys whose values are not the same in every one of ``experiments``
    (:attr:`Run.experiment`; a key one of them lacks differs), in recipe order."""
    keys = dict.fromkeys(k for e in experiments for k in e)
    return [k for k in keys if len({_exact(e.get(k, _UNSET)) for e in experiments}) > 1]


def _names(task: str, method: str, by_print: dict[str, list[Run]]) -> dict[str, str]:
    """The names of the groups of one task and method that are several experiments, and the
    warning that says what tells them apart."""
    views = {fp: members[0].experiment for fp, members in by_print.items()}
    keys = differing_keys(list(views.values()))
    # a key left out of one experiment is at its default there: shown as that value
    defaults = recipe_defaults()
    views = {
        fp: {**{k: defaults[k] for k in keys if k in defaults and k not in v}, **v}
        for fp, v in views.items()
    }
    told = "; ".join(
        f"{k}: {' vs '.join(dict.fromkeys(_text(v.get(k, _UNSET)) for v in views.values()))}"
        for k in keys
    )
    log.warning(
        "%s %s: these runs are %d experiments, not seeds of one (%s): shown separately",
        task, method, len(views), told,
    )  # fmt: skip
    shown = keys[:SHOWN_KEYS]
    more = f", +{len(keys) - SHOWN_KEYS} more" if len(keys) > SHOWN_KEYS else ""
    told_apart = {
        fp: ", ".join(f"{k}={_text(v.get(k, _UNSET))}" for k in shown) + more
        for fp, v in views.items()
    }
    if len(set(told_apart.values())) < len(told_apart):  # values cut alike: the fingerprint
        told_apart = {fp: f"{fp}, {text}" for fp, text in told_apart.items()}
    return {fp: f"{method} [{text}]" for fp, text in told_apart.items()}


def _check_seeds(task: str, label: str, members: Sequence[Run]) -> None:
    seen: dict[tuple[int, str | None], Run] = {}
    for r in members:
        key = (r.seed, r.single_robot)
        if key in seen:
            robot = f" on {r.single_robot}" if r.single_robot else ""
            raise AnalysisError(
                f"{seen[key].path} and {r.path}: both are seed {r.seed}{robot} of one experiment "
                f"({task} {label}); a seed counts once: give the run directories to compare "
                "instead of their folder, or move one of them out of it"
            )
        seen[key] = r


def _warn_plugins(task: str, label: str, members: Sequence[Run]) -> None:
    """One warning where the seeds of one group were trained with different plugins."""
    seeds: dict[tuple[str, ...], list[int]] = {}
    for r in members:
        got = seeds.setdefault(r.plugins, [])
        if r.seed not in got:
            got.append(r.seed)
    if len(seeds) < 2:
        return
    told = "; ".join(
        f"seed{'s' if len(s) > 1 else ''} {', '.join(map(str, s))}: "
        f"{', '.join(plugins) if plugins else 'no plugin'}"
        for plugins, s in seeds.items()
    )
    log.warning(
        "%s %s: its seeds were trained with different plugins (%s); pooled, as plugins are not "
        "part of an experiment (plot them in separate commands where that changed the method)",
        task, label, told,
    )  # fmt: skip


#: the value of a key a recipe does not have
_UNSET = object()


def _exact(value: Any) -> str:
    return "unset" if value is _UNSET else json.dumps(value, sort_keys=True, default=str)


def _text(value: Any) -> str:
    """A key's value as shown: ``24000``, ``[hopper_3,hopper_4]``, ``null``, ``unset``."""
    if value is _UNSET:
        text = "unset"
    elif isinstance(value, str):
        text = value
    else:
        text = json.dumps(value, separators=(",", ":"), default=str).replace('"', "")
    return text if len(text) <= SHOWN_VALUE else text[: SHOWN_VALUE - 3] + "..."
