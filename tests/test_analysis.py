"""Figures and tables from run directories: fake runs (recipe, metrics, evals) and small networks."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from gcnt.analysis import curves, zeroshot
from gcnt.analysis.runs import AnalysisError, Run, find_runs, mean_stderr
from gcnt.cli import main

TRAIN = ["walker_2_main", "walker_4_main", "walker_5_main", "walker_7_main"]
TEST = ["walker_3_main", "walker_6_main"]


def fake_run(
    root: Path,
    method: str,
    seed: int,
    *,
    steps: list[int],
    level: float,
    old_format: bool = False,
    evals: dict[str, dict[str, float]] | None = None,
    task: str = "Walker++",
) -> Path:
    path = root / task.replace("+", "p") / method / f"seed{seed}"
    (path / "checkpoints").mkdir(parents=True)
    recipe = {
        "seed": seed,
        "env": {"robots": ["Walker++:train"], "test_robots": ["Walker++:test"]},
        "collector": {"total_frames": steps[-1]},
        "network": {"name": method},
    }
    if old_format:
        recipe["benchmark"] = task
    else:
        recipe |= {"task": task, "algo": "td3"}
        recipe["env"]["benchmark"] = "smpenv"
    (path / "recipe.yaml").write_text(yaml.safe_dump(recipe))
    rows = []
    for s in steps:
        row = {"env_steps": s, "train_return/mean": level * s / steps[-1] + seed}
        row |= {f"train_return/{r}": row["train_return/mean"] for r in TRAIN}
        rows.append(json.dumps(row))
    (path / "metrics.jsonl").write_text("\n".join(rows) + "\n{torn")
    (path / "checkpoints" / "last.pt").write_bytes(b"")
    for name, robots in (evals or {}).items():
        data = {
            "env_steps": steps[-1],
            "robots": {
                r: {"mean": v, "stderr": 1.0, "episodes": 5, "returns": [v] * 5}
                for r, v in robots.items()
            },
        }
        if name.startswith("test"):
            data |= {"robots_spec": ["test"], "episodes": 5, "seed": 1, "deterministic": True}
        (path / "eval").mkdir(exist_ok=True)
        (path / "eval" / f"{name}.json").write_text(json.dumps(data))
    return path


@pytest.fixture
def sweep(tmp_path: Path) -> Path:
    for method, level in (("gcnt", 300.0), ("swat", 200.0), ("amorpheus", 100.0)):
        for seed in (0, 1):
            # seeds log at different steps: aggregation must interpolate
            steps = [1000, 2000, 3000, 4000] if seed == 0 else [1500, 2500, 4000]
            ev = {
                f"step{steps[-1]}": {r: level + seed for r in TRAIN + TEST},
                f"test-step{steps[-1]}-deterministic-seed10000": {
                    TEST[0]: level * 2 + seed,
                    TEST[1]: 50.0 * seed,
                },
            }
            fake_run(tmp_path, method, seed, steps=steps, level=level, evals=ev)
    return tmp_path


def test_find_runs_reads_new_and_old_recipes(tmp_path: Path) -> None:
    fake_run(tmp_path, "gcnt", 0, steps=[10, 20], level=1.0)
    fake_run(tmp_path, "swat", 3, steps=[10, 20], level=1.0, old_format=True, task="Cheetah++")
    runs = find_runs([tmp_path])
    assert [(r.task, r.method, r.seed, r.algo) for r in runs] == [
        ("Cheetah++", "swat", 3, "td3"),
        ("Walker++", "gcnt", 0, "td3"),
    ]
    assert all(r.finished() for r in runs)
    assert runs[1].test_robot_names() == TEST
    assert runs[1].metrics()[-1]["env_steps"] == 20  # the torn line is skipped
    with pytest.raises(AnalysisError, match="no run directories"):
        find_runs([tmp_path / "Walkerpp" / "gcnt" / "seed0" / "checkpoints"])
    with pytest.raises(AnalysisError, match="nope does not exist"):
        find_runs([tmp_path / "nope"])


def test_mean_stderr() -> None:
    m, se = mean_stderr([1.0, 3.0])
    assert m == 2.0 and se == pytest.approx(1.0)
    assert math.isnan(mean_stderr([5.0])[1])


def test_seeds_are_interpolated_onto_a_common_grid(sweep: Path) -> None:
    rows = curves.learning_curves(find_runs([sweep]), points=7)
    gcnt = [r for r in rows if r["method"] == "gcnt"]
    assert len(gcnt) == 7 and all(r["seeds"] == 2 for r in gcnt)
    # the grid is what both seeds cover: from the later first log to the earlier last one
    assert gcnt[0]["env_steps"] == 1500 and gcnt[-1]["env_steps"] == 4000
    # seed 1 is seed 0 shifted by +1 (linear in steps), so mean = seed-0 value + 0.5, s.e. = 0.5
    last = gcnt[-1]
    assert last["mean"] == pytest.approx(300.5) and last["stderr"] == pytest.approx(0.5)
    assert [r["method"] for r in rows[::7]] == ["gcnt", "swat", "amorpheus"]


def test_curves_command_writes_png_and_csv(sweep: Path, capsys) -> None:
    assert main(["curves", str(sweep), "--points", "5"]) == 0
    png, csv = sweep / "figures" / "curves.png", sweep / "figures" / "curves.csv"
    assert png.stat().st_size > 1000 and png.read_bytes()[:4] == b"\x89PNG"
    lines = csv.read_text().splitlines()
    assert lines[0] == "task,method,env_steps,mean,stderr,seeds,robots,logged,length_mean"
    assert len(lines) == 1 + 3 * 5
    assert main(["curves", str(sweep), "--metric", "nope"]) == 2


def test_zero_shot_table(sweep: Path) -> None:
    table = zeroshot.zero_shot_table(find_runs([sweep]))
    t = table["Walker++"]
    assert t["robots"] == TEST and t["methods"] == ["gcnt", "swat", "amorpheus"]
    cell = t["cells"][TEST[0]]["gcnt"]
    # per seed the latest, largest evaluation; the training and the test evaluation tie on steps
    # and episodes, and the test one wins: 600 + seed; over seeds mean ± s.e.
    assert cell["seeds"] == 2 and cell["per_seed"] == {"0": 600.0, "1": 601.0}
    assert cell["mean"] == pytest.approx(600.5) and cell["stderr"] == pytest.approx(0.5)
    assert all("test-step" in src for src in cell["sources"])
    assert t["best"][TEST[0]] == "gcnt"
    assert all(
        t["best"][r] is None
        for r in TEST[1:]
        if len({c["mean"] for c in t["cells"][r].values()}) == 1
    )
    md = zeroshot.to_markdown(table)
    assert "| robot | GCNT | SWAT | AMORPHEUS |" in md  # methods by their display names
    # bold only where the best's mean ± s.e. clears the runner-up's: walker_3_main's GCNT, not
    # walker_6_main's three equal means
    assert "| walker_3_main | **600.5 ± 0.5** |" in md and md.count("**") == 2
    # the table says what its numbers are
    assert t["protocol"] == cell["protocol"] == "deterministic actions, 5 episodes per robot"
    assert "Evaluation: deterministic actions, 5 episodes per robot." in md


def test_zero_shot_prefers_more_episodes_then_says_what_is_missing(tmp_path: Path) -> None:
    run = fake_run(tmp_path, "gcnt", 0, steps=[10], level=1.0, evals={"step10": {TEST[0]: 1.0}})
    big = {"env_steps": 10, "robots": {TEST[0]: {"mean": 7.0, "episodes": 100}}}
    (run / "eval" / "test-step10.json").write_text(json.dumps(big))
    t = zeroshot.zero_shot_table([Run(run)])["Walker++"]
    assert t["cells"][TEST[0]]["gcnt"]["mean"] == 7.0
    empty = fake_run(tmp_path, "swat", 0, steps=[10], level=1.0)
    with pytest.raises(AnalysisError, match="gcnt eval"):
        zeroshot.zero_shot_table([Run(empty)])


def _with_provenance(sweep: Path) -> str:
    """The caption of the sweep's runs, one of which records the code it ran (commit abc1234)."""
    from gcnt.run import provenance

    runs = find_runs([sweep])
    session = {"gcnt_version": "0.1.0", "git_commit": "abc1234" + "0" * 33, "git_dirty": False}
    provenance.add_session(runs[0].path, session)
    expected = "runs from gcnt 0.1.0 at commit abc1234 (1 run); provenance not recorded (5 runs)"
    assert provenance.caption(r.path for r in runs) == expected
    return expected


def test_zeroshot_command(sweep: Path, capsys) -> None:
    caption = _with_provenance(sweep)
    assert main(["zeroshot", str(sweep), "--out", str(sweep / "t")]) == 0
    strict = {"parse_constant": lambda c: pytest.fail(f"non-strict JSON: {c}")}
    data = json.loads((sweep / "t" / "zeroshot.json").read_text(), **strict)
    assert set(data["Walker++"]["cells"]) == set(TEST)
    md = (sweep / "t" / "zeroshot.md").read_text()
    assert "walker_3_main" in md and md.rstrip().endswith(f"_{caption}_")
    assert (sweep / "t" / "zeroshot.caption.txt").read_text() == caption + "\n"
    assert f"% {caption}" in (sweep / "t" / "zeroshot.tex").read_text()
    assert caption in capsys.readouterr().out


def test_the_zeroshot_caption_counts_the_runs_its_table_shows(tmp_path: Path, capsys) -> None:
    """Three runs, one with test robots evaluated: a table of one run, captioned "(1 run)"."""
    from test_variants import gcnt_eval
    from test_variants import make_run as variant_run

    from gcnt.run import provenance

    shown = variant_run(tmp_path, "gcnt", 0)
    gcnt_eval(shown, {TEST[0]: 5.0})
    variant_run(tmp_path, "gcnt", 1)  # no evaluation
    untested = variant_run(tmp_path, "swat", 0)  # no test robots
    recipe = yaml.safe_load((untested / "recipe.yaml").read_text())
    recipe["env"]["test_robots"] = []
    (untested / "recipe.yaml").write_text(yaml.safe_dump(recipe))
    session = {"gcnt_version": "0.1.0", "git_commit": "abc1234" + "0" * 33, "git_dirty": False}
    for run in find_runs([tmp_path]):
        provenance.add_session(run.path, session)
    out = tmp_path / "t"
    assert main(["zeroshot", str(tmp_path), "--out", str(out)]) == 0
    expected = "runs from gcnt 0.1.0 at commit abc1234 (1 run)"
    assert (out / "zeroshot.caption.txt").read_text() == expected + "\n"
    assert expected in capsys.readouterr().out
    table = json.loads((out / "zeroshot.json").read_text())
    assert [r.path for r in zeroshot.shown_runs(table, find_runs([tmp_path]))] == [shown]


def test_variants_command(sweep: Path) -> None:
    caption = _with_provenance(sweep)
    assert (
        main(["variants", str(sweep), "--sets", "test", "--iqm", "--profile", "--reps", "200"]) == 0
    )
    # the figure's caption, then the code of the runs (the caption's first letter capitalised)
    text = (sweep / "figures" / "variants.caption.txt").read_text()
    assert text.startswith("Zero-shot return per method. Error bars:")
    assert text.endswith(f" {caption[0].upper()}{caption[1:]}.\n")
    assert (sweep / "figures" / "variants.md").read_text().rstrip().endswith(f"_{text.strip()}_")
    data = json.loads((sweep / "figures" / "variants.json").read_text())
    assert set(data["test"]) == {"gcnt", "swat", "amorpheus"}
    est = data["test"]["gcnt"]["mean"]
    assert est["low"] <= est["point"] <= est["high"]
    # the test set is the test evaluation's 2 robots, not training's evaluation of all 6
    assert data["test"]["gcnt"]["robots"] == len(TEST)
    assert (sweep / "figures" / "variants.png").read_bytes()[:4] == b"\x89PNG"
    # no such evaluations: exit 2 naming what exists
    assert main(["variants", str(sweep), "--sets", "kinematics"]) == 2


def test_embed_untrained_gcnt_and_swat(tmp_path: Path) -> None:
    from gcnt.analysis.embed import structural_vectors
    from gcnt.morphology.catalogues import resolve_robots

    kw = {"d_model": 12, "layers": 1, "ff": 16, "heads": 2}
    robots = ["walker_2_main", "walker_3_main", "hopper_3"]
    g = structural_vectors("gcnt", robots, kwargs=kw)
    s = structural_vectors("swat", robots, kwargs=kw)
    sizes = {r.name: r.num_limbs for r in resolve_robots(robots)}
    limbs = sum(sizes.values())
    for e in (g, s):
        assert e.vectors.shape == (limbs, 12) and len(e.limb_types) == limbs
        assert e.robots.count("walker_3_main") == sizes["walker_3_main"]
        assert "torso" in e.limb_types and "thigh" in e.limb_types
    # the same limb type at the same place in two robots: same GCNT vector is not required,
    # but vectors must differ between limb types
    assert not np.allclose(g.vectors[0], g.vectors[1])
    with pytest.raises(AnalysisError, match="structural"):
        structural_vectors("amorpheus", robots, kwargs=kw)


def test_embed_command_untrained(tmp_path: Path) -> None:
    out = tmp_path / "fig"
    argv = ["embed", "--untrained", "gcnt,swat", "--robots", "Walker++:all", "--out", str(out)]
    assert main(argv) == 0
    assert (out / "embed.png").read_bytes()[:4] == b"\x89PNG"


def test_tables_markdown() -> None:
    from gcnt.analysis.tables import params_table, rows_to_markdown

    md = rows_to_markdown([{"method": "gcnt", "actor": 10, "critic": 5, "paper": None}])
    assert "| gcnt | 10 | 5 | 15 | – |" in md
    text, rows = params_table("smpenv")  # the rows by method id, the Markdown by display name
    gcnt = next(r for r in rows if r["method"] == "gcnt")
    assert text.startswith("| method | actor | critic | total | paper |")
    assert f"| GCNT | {gcnt['actor']:,} | {gcnt['critic']:,} | {gcnt['total']:,} |" in text
    assert "| SWAT |" in text


def test_eval_labels_old_and_new_file_names(sweep: Path) -> None:
    run = find_runs([sweep])[0]
    labels = sorted((e.label, e.env_steps) for e in run.evals())
    assert labels == [("", 4000), ("test", 4000)]
    assert [e.matches("test") for e in sorted(run.evals(), key=lambda e: e.label)] == [False, True]


def test_default_variant_sets_match_gcnt_eval_of_the_unimal_splits() -> None:
    """`gcnt variants`' default sets are the names `gcnt eval --robots Unimal:variants-...`
    leaves in its evaluation files."""
    from gcnt.analysis.runs import EvalRecord
    from gcnt.commands import variants as cmd
    from gcnt.commands.eval import _label

    parser = argparse.ArgumentParser()
    cmd.add_arguments(parser)
    sets = parser.parse_args(["x"]).sets.split(",")
    for spec, name in zip(
        ["Unimal:variants-kinematics", "Unimal:variants-dynamics"], sets, strict=True
    ):
        rec = EvalRecord(Path(f"{_label([spec])}-step10.json"), _label([spec]), 10, {},
                         {"robots_spec": [spec]})  # fmt: skip
        assert rec.matches(name)
        assert not rec.matches(sets[1 - sets.index(name)])


def test_embed_and_strobe_read_a_trained_run(tmp_path: Path) -> None:
    """The trained-run paths of `gcnt embed` and `gcnt strobe`: the actor's weights come from the
    run's checkpoint (`Run.policy_state`), one run per method by default."""
    root = Path(__file__).parents[1]
    run = tmp_path / "run"
    tiny = [
        "network.kwargs={d_model: 16, layers: 1, ff: 16, heads: 2}",
        "env.max_episode_steps=15",
        "td3.init_random_frames=30",
        "td3.steps_per_batch=5",
        "td3.batch_size=8",
        "logger.backend=none",
        "logger.progress=false",
        "collector.total_frames=60",
        "eval.episodes=1",
        f"run_dir={run}",
    ]
    assert main(["train", str(root / "recipes/quickstart.yaml"), *tiny]) == 0
    state = find_runs([run])[0].policy_state()
    assert set(state) >= {"actor"} and state["actor"]
    out = tmp_path / "fig"
    argv = ["embed", str(run), "--robots", "Hopper++:all", "--out", str(out)]
    assert main(argv) == 0
    assert (out / "embed.png").read_bytes()[:4] == b"\x89PNG"
    assert (
        main(["strobe", str(run), "--robot", "hopper_3", "--steps", "20", "--out", str(out)]) == 0
    )
    assert len(list(out.glob("strobe-hopper_3-*.png"))) == 1
    (run / "checkpoints" / "last.pt").write_bytes(b"not a checkpoint")
    assert main(["embed", str(run), "--out", str(out)]) == 2  # one line naming the file
