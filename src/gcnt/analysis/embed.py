"""Structural embeddings of limbs (paper figure 10): t-SNE of what a network adds to each limb's
observation embedding from the robot's structure alone.

* GCNT: the projected [GCN ‖ WL] features, ``Linear([GCN ‖ WL])`` of the fusion stage;
* SWAT: the traversal position embeddings ``[E_pre ‖ E_in ‖ E_post]``.

Both stages write ``limbs/hidden = limbs/embed + structural vector``, so a chain built with
``keep_intermediates=True`` gives the vector as ``hidden - embed``; it depends on the robot's
graph only, never on the observation. Works from a run's checkpoint or an untrained network.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gcnt.analysis.runs import AnalysisError, Run

#: methods whose chains carry a structural vector per limb
STRUCTURAL_METHODS = ("gcnt", "gcnt_no_gcn", "gcnt_no_wl", "gcnt_no_dist", "swat")
DEFAULT_ROBOTS = ("CWHH++:all",)


@dataclass
class Embedding:
    """Structural vectors of every real limb of some robots, from one network."""

    title: str
    vectors: np.ndarray  # [N, d]
    limb_types: list[str]  # [N]
    robots: list[str]  # [N]


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

    if method not in STRUCTURAL_METHODS:
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
        raise AnalysisError(f"{method}: the chain wrote no {K.HIDDEN} / {K.EMBED} intermediates")
    vec = (out.get(K.HIDDEN) - out.get(K.EMBED)).numpy()
    rows, limb_types, names = [], [], []
    for i, robot in enumerate(robots):  # limbs 0..n-1 of each robot are its real limbs
        for j in range(robot.num_limbs):
            rows.append(vec[i, j])
            t = int(robot.global_types[j])
            limb_types.append(GLOBAL_LIMB_TYPES[t] if 0 <= t < len(GLOBAL_LIMB_TYPES) else str(t))
            names.append(robot.name)
    return Embedding(title or method, np.stack(rows), limb_types, names)


def run_embedding(run: Run, robot_specs: Sequence[str] = DEFAULT_ROBOTS) -> Embedding:
    """Structural vectors of a run's trained actor (its latest checkpoint)."""
    net = run.recipe.get("network") or {}
    actor_state = run.policy_state()["actor"]
    return structural_vectors(
        run.method,
        robot_specs,
        actor_state=actor_state,
        benchmark=run.benchmark,
        preset=net.get("preset"),
        kwargs=dict(net.get("kwargs") or {}),
        role="ppo_actor" if run.algo == "ppo" else "td3_actor",
        title=f"{run.method} ({run.task}, seed {run.seed}, {run.last_env_steps()} steps)",
    )


def tsne(vectors: np.ndarray, seed: int = 0, perplexity: float = 30.0) -> np.ndarray:
    """2-d t-SNE of ``vectors`` (scikit-learn); perplexity capped below the number of points."""
    from sklearn.manifold import TSNE

    n = len(vectors)
    if n < 3:
        raise AnalysisError(f"t-SNE needs at least 3 limbs, got {n}")
    perplexity = float(min(perplexity, (n - 1) / 3))
    return TSNE(2, perplexity=perplexity, init="pca", random_state=seed).fit_transform(
        vectors.astype(np.float64)
    )


MARKERS = "os^vD<>pP*Xhd8H"


def plot_embeddings(embeddings: Sequence[Embedding], path: Path, seed: int = 0) -> Path:
    """t-SNE panels side by side: colour = limb type, marker = robot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    types = sorted({t for e in embeddings for t in e.limb_types})
    robots = list(dict.fromkeys(r for e in embeddings for r in e.robots))
    colour = {t: plt.get_cmap("tab10")(i % 10) for i, t in enumerate(types)}
    marker = {r: MARKERS[i % len(MARKERS)] for i, r in enumerate(robots)}
    fig, axes = plt.subplots(1, len(embeddings), figsize=(5.2 * len(embeddings), 5), squeeze=False)
    for ax, e in zip(axes[0], embeddings, strict=True):
        xy = tsne(e.vectors, seed)
        for r in robots:
            idx = [i for i, name in enumerate(e.robots) if name == r]
            if idx:
                ax.scatter(
                    xy[idx, 0],
                    xy[idx, 1],
                    c=[colour[e.limb_types[i]] for i in idx],
                    marker=marker[r],
                    s=28,
                    alpha=0.8,
                    linewidths=0,
                )
        ax.set_title(e.title, fontsize="medium")
        ax.set_xticks([])
        ax.set_yticks([])
    handles = [Line2D([], [], ls="", marker="o", color=colour[t], label=t) for t in types]
    handles += [Line2D([], [], ls="", marker=marker[r], color="0.4", label=r) for r in robots]
    fig.legend(
        handles=handles,
        loc="center left",
        bbox_to_anchor=(1.0, 0.5),
        fontsize="x-small",
        ncols=1 + len(handles) // 30,
        title="limb type (colour) / robot (marker)",
        title_fontsize="small",
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path
