"""Structural embeddings of limbs (paper figure 10): t-SNE of what a network adds to each limb's
observation embedding from the robot's structure alone.

* GCNT: the projected [GCN ‖ WL] features, ``Linear([GCN ‖ WL])`` of the fusion stage;
* SWAT: the traversal position embeddings ``[E_pre ‖ E_in ‖ E_post]``;
* a plugin's method whose chain writes ``limbs/hidden`` and ``limbs/embed``.

Both stages write ``limbs/hidden = limbs/embed + structural vector``, so a chain built with
``keep_intermediates=True`` gives the vector as ``hidden - embed``; it depends on the robot's
graph only, never on the observation. Works from a run's checkpoint or an untrained network.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gcnt.analysis.plotting import FigureStyle
from gcnt.analysis.runs import AnalysisError, Run

#: methods whose chains carry a structural vector per limb
STRUCTURAL_METHODS = (
    "gcnt",
    "gcnt_no_gcn",
    "gcnt_no_wl",
    "gcnt_no_dist",
    "gcnt_dist_first",
    "gcnt_gcn_context",
    "swat",
)
DEFAULT_ROBOTS = ("CWHH++:all",)


class NoStructureError(AnalysisError):
    """A method whose chain has no per-limb structural vector."""


def has_structure(method: str) -> bool:
    """Whether ``method`` may have a structural vector: gcnt's methods that have one, and any
    method of a plugin (its chain is checked when built: :class:`NoStructureError`)."""
    from gcnt.nn.registry import BUILTIN_NETWORKS, NETWORKS

    return method in STRUCTURAL_METHODS or (method in NETWORKS and method not in BUILTIN_NETWORKS)


@dataclass
class Embedding:
    """Structural vectors of every real limb of some robots, from one network."""

    title: str
    vectors: np.ndarray  # [N, d]
    limb_types: list[str]  # [N]
    robots: list[str]  # [N]
    families: list[str]  # [N] robot family of each limb's robot (walker, cheetah, ...)


def _widths(benchmark: str) -> tuple[int, int, str]:
    """(limb observation width, action slots, size preset) of a benchmark."""
    from gcnt.envs.benchmark import get_benchmark

    b = get_benchmark(benchmark)
    return b.limb_obs_dim, b.action_slots, b.preset


def structural_vectors(
    method: str,
    robot_specs: Sequence[str] = DEFAULT_ROBOTS,
    *,
    actor_state: dict[str, Any] | None = None,
    benchmark: str = "smpenv",
    preset: str | None = None,
    kwargs: dict[str, Any] | None = None,
    role: str = "td3_actor",
    title: str | None = None,
) -> Embedding:
    """Per-limb structural vectors of ``method``'s actor (trained weights if ``actor_state``)."""
    import torch
    from tensordict import TensorDict

    from gcnt import keys as K
    from gcnt.morphology.catalogues import resolve_robots
    from gcnt.morphology.limb_types import GLOBAL_LIMB_TYPES
    from gcnt.nn.registry import make_network

    if not has_structure(method):
        raise AnalysisError(
            f"method {method!r} has no per-limb structural vector "
            f"(these do: {', '.join(STRUCTURAL_METHODS)})"
        )
    robots = resolve_robots(list(robot_specs))
    obs_dim, slots, bench_preset = _widths(benchmark)
    actor = make_network(
        method,
        role,
        table=robots,
        obs_dim=obs_dim,
        num_actions=slots,
        preset=preset or bench_preset,
        keep_intermediates=True,
        **(kwargs or {}),
    )
    if actor_state is not None:
        try:
            missing, unexpected = actor.load_state_dict(actor_state, strict=False)
        except RuntimeError as e:  # shapes differ: a checkpoint from another gcnt version
            detail = " ".join(str(e).split("\n")[1:2]).strip()
            raise AnalysisError(
                f"{title or method}: the checkpoint's actor does not fit the network built "
                f"here ({detail})"
            ) from None
        missing = [k for k in missing if not k.rsplit(".", 1)[-1].startswith("table_")]
        if missing or unexpected:
            raise AnalysisError(
                f"{method}: the checkpoint's actor does not fit the network "
                f"(missing {missing[:3]}, unexpected {list(unexpected)[:3]})"
            )
    actor.eval()
    k = max(r.num_limbs for r in robots)
    td = TensorDict(
        {
            K.MORPH_ID: torch.arange(len(robots)),
            K.OBS: torch.zeros(len(robots), k, obs_dim),
        },
        batch_size=[len(robots)],
    )
    with torch.no_grad():
        out = actor(td)
    if K.HIDDEN not in out.keys(True) or K.EMBED not in out.keys(True):
        raise NoStructureError(
            f"{method}: its chain writes no limbs/hidden and limbs/embed intermediates (the "
            "structural vector is hidden - embed)"
        )
    vec = (out.get(K.HIDDEN) - out.get(K.EMBED)).numpy()
    rows, limb_types, names, families = [], [], [], []
    for i, robot in enumerate(robots):  # limbs 0..n-1 of each robot are its real limbs
        for j in range(robot.num_limbs):
            rows.append(vec[i, j])
            t = int(robot.global_types[j])
            limb_types.append(GLOBAL_LIMB_TYPES[t] if 0 <= t < len(GLOBAL_LIMB_TYPES) else str(t))
            names.append(robot.name)
            families.append(robot.family)
    return Embedding(title or method, np.stack(rows), limb_types, names, families)


def run_embedding(
    run: Run, robot_specs: Sequence[str] = DEFAULT_ROBOTS, names: Mapping[str, str] | None = None
) -> Embedding:
    """Structural vectors of a run's trained actor (its latest checkpoint), titled with the
    display names of its method and task (``names`` over the defaults)."""
    from gcnt.analysis.names import display_name
    from gcnt.recipes import NetworkConfig

    net = run.recipe.get("network") or {}
    actor_state = run.policy_state()["actor"]
    return structural_vectors(
        run.method,
        robot_specs,
        actor_state=actor_state,
        benchmark=run.benchmark,
        preset=net.get("preset"),
        kwargs=NetworkConfig(
            name=run.method,
            kwargs=dict(net.get("kwargs") or {}),
            method_kwargs=dict(net.get("method_kwargs") or {}),
        ).sizes(),
        role="ppo_actor" if run.algo == "ppo" else "td3_actor",
        title=f"{display_name(run.method, names)} ({display_name(run.task, names)}, "
        f"seed {run.seed}, {run.last_env_steps()} steps)",
    )


def tsne(vectors: np.ndarray, seed: int = 0, perplexity: float = 30.0) -> np.ndarray:
    """2-d t-SNE of ``vectors`` (scikit-learn); perplexity capped below the number of points."""
    from gcnt.extras import require

    TSNE = require("sklearn.manifold", "a t-SNE of limb embeddings").TSNE  # noqa: N806 (a class)

    n = len(vectors)
    if n < 3:
        raise AnalysisError(f"t-SNE needs at least 3 limbs, got {n}")
    perplexity = float(min(perplexity, (n - 1) / 3))
    return TSNE(2, perplexity=perplexity, init="pca", random_state=seed).fit_transform(
        vectors.astype(np.float64)
    )


#: marker of each robot family; a family not listed takes the next of ``SPARE_MARKERS``
FAMILY_MARKERS = {"walker": "o", "cheetah": "s", "hopper": "D", "humanoid": "^", "unimal": "P"}
SPARE_MARKERS = "v<>pX*hd"


def _family_markers(families: Sequence[str]) -> dict[str, str]:
    spare = iter(SPARE_MARKERS)
    return {f: FAMILY_MARKERS.get(f) or next(spare, "o") for f in families}


def _type_colours(types: Sequence[str]) -> dict[str, Any]:
    """One tab10 colour per limb type, fixed by its place in ``GLOBAL_LIMB_TYPES`` so that a type
    keeps its colour across figures."""
    from gcnt.analysis.plotting import pyplot

    plt = pyplot()

    from gcnt.morphology.limb_types import GLOBAL_LIMB_TYPES

    cmap = plt.get_cmap("tab10")
    known = [t for t in GLOBAL_LIMB_TYPES if t in types]
    other = sorted(t for t in types if t not in GLOBAL_LIMB_TYPES)
    slots = [GLOBAL_LIMB_TYPES.index(t) for t in known]
    slots += range(len(GLOBAL_LIMB_TYPES), len(GLOBAL_LIMB_TYPES) + len(other))
    return {t: cmap(i % 10) for t, i in zip(known + other, slots, strict=True)}


def embedding_figure(
    embeddings: Sequence[Embedding],
    coords: Sequence[np.ndarray],
    style: FigureStyle | None = None,
):
    """t-SNE panels side by side (``coords[i]``: [N, 2] points of ``embeddings[i]``): marker =
    robot family, colour = limb type, with one legend for each below the panels; size, fonts
    and title as ``style`` says."""
    style = style or FigureStyle()
    with style.context():
        return _embedding_figure(embeddings, coords, style)


def _embedding_figure(
    embeddings: Sequence[Embedding], coords: Sequence[np.ndarray], style: FigureStyle
):
    from gcnt.analysis.plotting import pyplot

    plt = pyplot()
    from matplotlib.lines import Line2D

    from gcnt.morphology.limb_types import FAMILIES

    if len(coords) != len(embeddings):
        raise ValueError(f"{len(embeddings)} embeddings but {len(coords)} coordinate arrays")
    seen = {f for e in embeddings for f in e.families}
    families = [f for f in FAMILIES if f in seen] + sorted(seen - set(FAMILIES))
    marker = _family_markers(families)
    colour = _type_colours(sorted({t for e in embeddings for t in e.limb_types}))
    n = len(embeddings)
    fig, axes = plt.subplots(1, n, figsize=style.size((3.6 * n, 3.6)), squeeze=False)
    for ax, e, xy in zip(axes[0], embeddings, coords, strict=True):
        xy = np.asarray(xy)
        if xy.shape != (len(e.vectors), 2):
            raise ValueError(
                f"{e.title}: coordinates of shape {xy.shape}, not ({len(e.vectors)}, 2)"
            )
        for f in families:
            idx = [i for i, fam in enumerate(e.families) if fam == f]
            if idx:
                ax.scatter(
                    xy[idx, 0],
                    xy[idx, 1],
                    c=[colour[e.limb_types[i]] for i in idx],
                    marker=marker[f],
                    s=30,
                    alpha=0.85,
                    edgecolors="0.15",
                    linewidths=0.4,
                )
        ax.set_title(e.title, fontsize="small")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_aspect("equal", adjustable="datalim")
    style.suptitle(fig)
    fig.tight_layout()
    fam_handles = [
        Line2D([], [], ls="", marker=marker[f], mfc="0.75", mec="0.15", label=f) for f in families
    ]
    type_handles = [
        Line2D([], [], ls="", marker="o", mfc=c, mec="0.15", label=t) for t, c in colour.items()
    ]
    common = {"fontsize": "small", "title_fontsize": "small", "frameon": False}
    common |= {"handletextpad": 0.2, "columnspacing": 0.8}
    fig.legend(
        handles=fam_handles,
        title="robot family (marker)",
        loc="upper right",
        bbox_to_anchor=(0.48, 0.0),
        ncols=max(1, (len(fam_handles) + 1) // 2),
        **common,
    )
    fig.legend(
        handles=type_handles,
        title="limb type (colour)",
        loc="upper left",
        bbox_to_anchor=(0.52, 0.0),
        ncols=max(1, (len(type_handles) + 1) // 2),
        **common,
    )
    return fig


def plot_embeddings(
    embeddings: Sequence[Embedding], path: Path, seed: int = 0, style: FigureStyle | None = None
) -> Path:
    """:func:`embedding_figure` of the t-SNE of each embedding, written as ``style`` says
    (default: to ``path``); returns the first file written."""
    style = style or FigureStyle()
    fig = embedding_figure(embeddings, [tsne(e.vectors, seed) for e in embeddings], style)
    return style.save(fig, path)[0]
