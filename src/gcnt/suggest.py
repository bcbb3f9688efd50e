"""One "did you mean" for every error about an unknown name (recipe keys, robots, networks...)."""

from __future__ import annotations

import difflib
from collections.abc import Iterable
from pathlib import Path

#: what other codebases call a recipe key gcnt names otherwise (a misspelling of the alias is
#: pointed at gcnt's key first)
KEY_ALIASES = {
    "learning_rate": "lr",
    "actor_lr": "lr",
    "critic_lr": "lr",
    "discount": "gamma",
    "polyak": "tau",
    "target_update_rate": "tau",
    "policy_freq": "policy_delay",
    "policy_frequency": "policy_delay",
    "expl_noise": "exploration_noise",
    "start_timesteps": "init_random_frames",
    "learning_starts": "init_random_frames",
    "buffer_size": "buffer_size_per_robot",
    "grad_clip": "max_grad_norm",
    "grad_clipping_value": "max_grad_norm",
    "clip_coef": "clip_epsilon",
    "clip_range": "clip_epsilon",
    "n_epochs": "epochs",
    "num_epochs": "epochs",
}


def did_you_mean(
    name: str,
    known: Iterable[str],
    n: int = 3,
    ignore_case: bool = False,
    aliases: dict[str, str] | None = None,
) -> str:
    """``"; did you mean 'a' or 'b'?"`` for the closest entries of ``known``, or ``""``
    (``ignore_case``: ``GCNT`` is close to ``gcnt``; ``aliases``: other names of known entries,
    whose entries come first where ``name`` is close to the alias)."""
    known = [str(k) for k in known]
    first: list[str] = []
    if aliases:
        near = difflib.get_close_matches(str(name).lower(), list(aliases), n=n, cutoff=0.75)
        first = [aliases[a] for a in near if aliases[a] in known]
    if ignore_case:
        spelt = {k.lower(): k for k in reversed(known)}
        lower = difflib.get_close_matches(str(name).lower(), list(spelt), n=n, cutoff=0.5)
        close = [spelt[k] for k in lower]
    else:
        close = difflib.get_close_matches(str(name), known, n=n, cutoff=0.5)
    close = list(dict.fromkeys([*first, *close]))[:n]
    return f"; did you mean {' or '.join(map(repr, close))}?" if close else ""


def existing_path(text: str, kind: str = "run directory") -> Path:
    """``text`` as a path that exists; a FileNotFoundError naming it as ``kind``, with the
    closest existing paths, otherwise (runs are stored under a slug of the task: ``runs/Walker++/...`` is
    ``runs/Walkerpp/...``)."""
    path = Path(text)
    if path.exists():
        return path
    hint = did_you_mean(text, _close_paths(path))
    raise FileNotFoundError(f"{kind} {text} does not exist{hint}")


def _close_paths(path: Path, depth: int = 0) -> list[str]:
    """Existing paths that differ from ``path`` in a few misspelt parts (up to 3)."""
    parts = path.parts
    i = next((i for i in range(len(parts)) if not Path(*parts[: i + 1]).exists()), len(parts))
    if i == len(parts):
        return [str(path)]
    parent = Path(*parts[:i]) if i else Path(".")
    if depth >= 3 or not parent.is_dir():
        return []
    try:
        names = [p.name for p in parent.iterdir() if p.is_dir() or i == len(parts) - 1]
    except OSError:  # a folder that cannot be listed
        return []
    # the task folder's name as RunDir.for_recipe spells it (runs/Walker++ -> runs/Walkerpp)
    slug = "".join(c if c.isalnum() or c in "-_" else "-" for c in parts[i].replace("+", "p"))
    close = ([slug] if slug in names else []) + difflib.get_close_matches(parts[i], names, 3, 0.5)
    found: list[str] = []
    for name in dict.fromkeys(close):
        found += _close_paths(parent.joinpath(name, *parts[i + 1 :]), depth + 1)
    return [str(Path(p)) for p in dict.fromkeys(found)][:3]
