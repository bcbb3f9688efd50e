"""``gcnt variants``: which evaluation and robots a set names, the protocol it states, and the
stratified bootstrap over seeds of each seed's aggregate (rliable's interval for few runs).

The run directories are written as runs write them: ``recipe.yaml`` with its ``resolved:``
section, training's evaluation ``eval/step<N>.json`` of the train and test robots, and ``gcnt
eval``'s ``eval/<label>-step<N>-<mode>-seed<S>.json``, both through ``write_eval``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from gcnt.analysis import variants
from gcnt.analysis.runs import Run, find_runs
from gcnt.cli import main
from gcnt.rl.evaluate import summarize, write_eval

TRAIN = ["walker_2_main", "walker_4_main", "walker_5_main", "walker_7_main"]
TEST = ["walker_3_main", "walker_6_main"]


def make_run(root: Path, method: str, seed: int, *, deterministic: bool = True) -> Path:
    path = root / method / f"seed{seed}"
    path.mkdir(parents=True)
    recipe = {
        "task": "Walker++",
        "algo": "td3",
        "seed": seed,
        "env": {
            "benchmark": "smpenv",
            "robots": ["Walker++:train"],
            "test_robots": ["Walker++:test"],
        },
        "collector": {"total_frames": 4000},
        "network": {"name": method},
        "eval": {"episodes": 10, "deterministic": deterministic},
        "resolved": {"init_random_frames": 1000},
    }
    (path / "recipe.yaml").write_text(yaml.safe_dump(recipe))
    return path


def training_eval(run: Path, level: float, steps: int = 4000, deterministic: bool = True) -> None:
    """What the run loop writes at the end: every train and test robot, ``eval.episodes``."""
    results = {r: summarize([level] * 10) for r in TRAIN + TEST}
    meta = {
        "robots_spec": ["Walker++:train", "Walker++:test"],
        "episodes": 10,
        "deterministic": deterministic,
    }
    write_eval(run / "eval" / f"step{steps}.json", results, steps, meta)


def gcnt_eval(
    run: Path, scores: dict[str, float], *, deterministic: bool = True, episodes: int = 100
) -> None:
    """What ``gcnt eval RUN --robots test`` writes."""
    results = {r: summarize([v] * episodes) for r, v in scores.items()}
    meta = {
        "robots_spec": ["test"],
        "resolved_specs": ["Walker++:test"],
        "episodes": episodes,
        "seed": 10000,
        "deterministic": deterministic,
    }
    mode = "det" if deterministic else "stoch"
    write_eval(run / "eval" / f"test-step4000-{mode}-seed10000.json", results, 4000, meta)


def test_the_test_set_is_the_test_robots_of_one_evaluation(tmp_path: Path) -> None:
    run = make_run(tmp_path, "gcnt", 0)
    training_eval(run, level=7.0)
    # only training's evaluation: the test set is its 2 test robots, never all 6
    r = Run(run)
    e, robots = variants.set_evaluation(r, r.evals(), "test")
    assert e.label == "" and robots == TEST
    assert sorted(variants.set_evaluation(r, r.evals(), "Walker++:train")[1]) == sorted(TRAIN)
    assert len(variants.set_evaluation(r, r.evals(), "training")[1]) == 6
    # a `gcnt eval --robots test` evaluation with more episodes: all of the set from it
    gcnt_eval(run, {TEST[0]: 1.0, TEST[1]: 3.0})
    item = variants.variant_summary([Run(run)], ["test"])["test"]["gcnt"]
    assert item["robots"] == 2 and item["scores"] == {"seed0": {TEST[0]: 1.0, TEST[1]: 3.0}}
    assert item["protocol"] == "deterministic actions, 100 episodes per robot"
    assert item["sources"] == [str(run / "eval" / "test-step4000-det-seed10000.json")]
    assert math.isnan(item["mean"]["low"])  # one seed: no interval
    # the resolved spec names the same evaluation
    assert variants.set_evaluation(r, Run(run).evals(), "Walker++:test")[0].label == "test"


def test_the_recipe_protocol_wins_between_equal_evaluations(tmp_path: Path) -> None:
    """A UNIMAL-like recipe (eval.deterministic: false): its sampled-action evaluation is the one
    read, although a deterministic one has more episodes."""
    run = make_run(tmp_path, "gcnt", 0, deterministic=False)
    gcnt_eval(run, {TEST[0]: 1.0, TEST[1]: 1.0}, deterministic=True, episodes=100)
    gcnt_eval(run, {TEST[0]: 5.0, TEST[1]: 5.0}, deterministic=False, episodes=32)
    item = variants.variant_summary([Run(run)], ["test"])["test"]["gcnt"]
    assert item["mean"]["point"] == 5.0
    assert item["protocol"] == "sampled actions, 32 episodes per robot"


def test_bootstrap_over_seeds_known_answers() -> None:
    # identical seeds: a zero-width interval
    assert variants.bootstrap_ci([3.0, 3.0, 3.0]) == (3.0, 3.0, 3.0)
    # two seeds a, b: resampled means are a, (a+b)/2 or b; the 95% interval is [a, b]
    point, lo, hi = variants.bootstrap_ci([2.0, 10.0], reps=4000)
    assert point == 6.0 and (lo, hi) == (2.0, 10.0)
    # deterministic given the bootstrap's seed
    x = np.random.default_rng(1).normal(size=5).tolist()
    assert variants.bootstrap_ci(x, seed=3) == variants.bootstrap_ci(x, seed=3)
    assert variants.bootstrap_ci(x, seed=3) != variants.bootstrap_ci(x, seed=4)
    p, lo, hi = variants.bootstrap_ci(x)
    assert min(x) <= lo <= p <= hi <= max(x)
    # stratified: seeds are resampled within each task, so two tasks whose seeds agree give no
    # spread, where pooling them would
    assert variants.bootstrap_ci([1.0, 1.0, 5.0, 5.0], ["A", "A", "B", "B"]) == (3.0, 3.0, 3.0)
    assert variants.bootstrap_ci([1.0, 1.0, 5.0, 5.0])[1] < 3.0
    # one seed per task: no interval
    assert math.isnan(variants.bootstrap_ci([1.0, 5.0], ["A", "B"])[1])
    assert math.isnan(variants.bootstrap_ci([])[0])


def test_interval_resamples_seeds_not_robots(tmp_path: Path) -> None:
    """Two seeds whose robots differ widely but whose aggregates agree: a zero-width interval
    (resampling seeds within each robot gave a spread); aggregates 2 and 4: the interval is
    [2, 4] around the mean 3, and the IQM is each seed's interquartile mean over robots."""
    for seed, shift in ((0, 0.0), (1, 0.0)):
        gcnt_eval(make_run(tmp_path, "gcnt", seed), {TEST[0]: -50.0 + shift, TEST[1]: 50.0})
    for seed, level in ((0, 2.0), (1, 4.0)):
        gcnt_eval(make_run(tmp_path, "swat", seed), {TEST[0]: level - 1, TEST[1]: level + 1})
    summary = variants.variant_summary(find_runs([tmp_path]), ["test"], ("mean", "iqm"))
    g, s = summary["test"]["gcnt"], summary["test"]["swat"]
    assert (g["mean"]["point"], g["mean"]["low"], g["mean"]["high"]) == (0.0, 0.0, 0.0)
    assert (s["mean"]["point"], s["mean"]["low"], s["mean"]["high"]) == (3.0, 2.0, 4.0)
    assert s["mean"]["per_seed"] == {"seed0": 2.0, "seed1": 4.0}
    assert s["iqm"]["per_seed"] == {"seed0": 2.0, "seed1": 4.0} and s["seeds"] == 2
    md = variants.to_markdown(summary, ("mean", "iqm"))
    # two seeds: the interval is their range and is called so, never a 95% CI
    assert "range of the seeds' aggregates over the set's robots (n = 2 seeds;" in md
    assert "CI" not in md.replace("no bootstrap CI", "")
    assert "Evaluation: deterministic actions, 100 episodes per robot." in md
    assert "| SWAT | 2 | 2 | 3.0 [2.0, 4.0] | 3.0 [2.0, 4.0] |" in md


def test_variants_command_states_interval_and_protocol(tmp_path: Path, capsys) -> None:
    for seed in (0, 1):
        run = make_run(tmp_path, "gcnt", seed)
        training_eval(run, level=10.0 + seed)
    argv = ["variants", str(tmp_path), "--sets", "test,Walker++:train", "--reps", "200"]
    assert main(argv) == 0
    text = (tmp_path / "figures" / "variants.md").read_text()
    assert "deterministic actions, 10 episodes per robot" in text
    data = json.loads(
        (tmp_path / "figures" / "variants.json").read_text(),
        parse_constant=lambda c: pytest.fail(f"non-strict JSON: {c}"),
    )
    assert data["test"]["gcnt"]["robots"] == 2 and data["Walker++:train"]["gcnt"]["robots"] == 4
    assert (tmp_path / "figures" / "variants.png").read_bytes()[:4] == b"\x89PNG"
    # the caption beside the figure, as text, Markdown and LaTeX: the error bars, the protocol
    # and the code of the runs
    caption = (tmp_path / "figures" / "variants.caption.txt").read_text().strip()
    assert caption.startswith("Zero-shot return per method. Error bars: range")
    assert "10 episodes per robot" in caption and caption.endswith("(2 runs).")
    assert text.rstrip().endswith(f"_{caption}_")
    tex = (tmp_path / "figures" / "variants.caption.tex").read_text()
    assert tex.startswith("\\caption{Zero-shot return per method.") and "n = 2 seeds" in tex
    assert main([*argv, "--reps", "0"]) == 2
