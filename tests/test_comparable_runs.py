"""Analysis pools only the seeds of one experiment: runs whose resolved recipes agree on all but
the seed and the keys that do not change the experiment (``Run.fingerprint``). Runs of one task
and method that are several experiments are split, named by the keys that tell them apart; a
seed given twice is refused naming both runs; a fine-tuned run (``--init-from``) gets a task of
its own, ``<source task>-ft``, and its recipe records its source's task and fingerprint.

Fake run directories are written as runs write them (``recipe.yaml`` with ``resolved:``,
``metrics.jsonl`` through ``RunDir.log_metrics``, ``eval/step<N>.json`` through
``write_eval``); the fine-tune test trains tiny runs.
"""

from __future__ import annotations

import copy
import logging
from pathlib import Path
from typing import Any

import pytest
import yaml
from cli_helpers import tiny_td3_recipe

from gcnt.analysis import curves, variants, zeroshot
from gcnt.analysis.groups import comparable_groups
from gcnt.analysis.runs import AnalysisError, Run, find_runs
from gcnt.cli import main
from gcnt.recipes import load_recipe
from gcnt.rl.evaluate import summarize, write_eval
from gcnt.rl.init_from import own_task
from gcnt.run.directory import RunDir

TRAIN = ["walker_2_main", "walker_4_main"]
TEST = ["walker_3_main"]

RECIPE: dict[str, Any] = {
    "task": "Walker++",
    "algo": "td3",
    "seed": 0,
    "device": "cpu",
    "run_dir": None,
    "env": {"benchmark": "smpenv", "robots": TRAIN, "test_robots": TEST, "num_threads": None},
    "collector": {"total_frames": 2400},
    "network": {"name": "gcnt"},
    "td3": {"init_random_frames": 600},
    "logger": {"backend": "wandb", "log_interval": 600},
    "eval": {"episodes": 2, "deterministic": True},
    "compile": {"compile": False, "amp": False},
    "resolved": {"init_random_frames": 600},
}


def _merge(base: dict, top: dict) -> dict:
    out = copy.deepcopy(base)
    for key, value in top.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def fake_run(path: Path, seed: int = 0, level: float = 0.0, **changes: Any) -> Path:
    """A finished run of :data:`RECIPE` with ``changes`` (``collector={"total_frames": N}``):
    a training return of ``level + seed`` at two log steps and a final evaluation of every train
    and test robot at ``10 * (level + seed)``."""
    recipe = _merge(RECIPE, {"seed": seed, **changes})
    path.mkdir(parents=True)
    (path / "recipe.yaml").write_text(yaml.safe_dump(recipe))
    run, total, value = RunDir(path), recipe["collector"]["total_frames"], level + seed
    for step in (total // 2, total):
        run.log_metrics({"env_steps": step, "train_return/mean": value})
    robots = recipe["env"]["robots"] + recipe["env"]["test_robots"]
    results = {r: summarize([10 * value] * 2) for r in robots}
    meta = {"robots_spec": robots, "episodes": 2, "deterministic": True}
    write_eval(path / "eval" / f"step{total}.json", results, total, meta)
    return path


def test_settings_that_do_not_change_the_experiment_keep_the_same_fingerprint(tmp_path):
    base = Run(fake_run(tmp_path / "a"))
    same = Run(
        fake_run(
            tmp_path / "b",
            seed=3,
            device="cuda",
            run_dir="elsewhere/seed3",
            logger={"backend": "none", "log_interval": 100, "tags": ["x"]},
            env={"num_threads": 1},
            compile={"compile": True, "torch_threads": 1},
            checkpoint_interval=50,
            eval={"interval": 1200, "video": True},
            resolved={"num_envs": 2},
            collector={"total_frames": 2.4e3},  # a float that is the same whole number
            init_from=None,  # null: as a recipe without the key
        )
    )
    assert same.fingerprint == base.fingerprint
    for name, change in (
        ("budget", {"collector": {"total_frames": 1200}}),
        ("random phase", {"td3": {"init_random_frames": 300}}),
        ("robots", {"env": {"robots": ["walker_2_main"]}}),
        ("bfloat16", {"compile": {"amp": True}}),
        ("protocol", {"eval": {"deterministic": False}}),
        ("fine-tune", {"init_from": "runs/src/seed0"}),
    ):
        assert Run(fake_run(tmp_path / name, **change)).fingerprint != base.fingerprint, name


def test_seeds_trained_with_different_plugins_are_pooled_with_one_warning(tmp_path, caplog):
    """Plugins are not part of an experiment (a plugin cannot replace a built-in method), but
    seeds trained with other plugins, or with another version of a plugin method's code, are not
    pooled without a word: one warning per group names each seed's plugins."""

    def plugins(name: str, sha: str) -> dict:
        return {"resolved": {"plugins": [{"name": name, "sha256": sha * 64}]}}

    fake_run(tmp_path / "gcnt" / "seed0", 0)
    fake_run(tmp_path / "gcnt" / "seed1", 1, **plugins("extra.py", "a"))
    mine = {"network": {"name": "meanmsg"}}
    fake_run(tmp_path / "mine" / "seed0", 0, **mine, **plugins("meanmsg.py", "0"))
    fake_run(tmp_path / "mine" / "seed1", 1, **mine, **plugins("meanmsg.py", "1"))
    fake_run(tmp_path / "mine" / "seed2", 2, **mine, **plugins("meanmsg.py", "0"))
    fake_run(tmp_path / "same" / "seed0", 0, network={"name": "swat"}, **plugins("x.py", "b"))
    fake_run(tmp_path / "same" / "seed1", 1, network={"name": "swat"}, **plugins("x.py", "b"))
    with caplog.at_level(logging.WARNING, logger="gcnt.analysis.groups"):
        groups = comparable_groups(find_runs([tmp_path]))
    assert [(g.label, len(g.runs)) for g in groups] == [("gcnt", 2), ("swat", 2), ("meanmsg", 3)]
    said = [m for m in caplog.messages if "trained with different plugins" in m]
    assert len(said) == 2, caplog.messages
    gcnt, mine = said
    assert gcnt.startswith("Walker++ gcnt:")
    assert "seed 0: no plugin; seed 1: extra.py sha256 aaaaaaaaaaaaaaaa)" in gcnt
    assert "seeds 0, 2: meanmsg.py sha256 0000" in mine and "seed 1: meanmsg.py sha256 1111" in mine


def test_per_robot_runs_are_one_experiment_whatever_their_robot(tmp_path):
    a = Run(fake_run(tmp_path / "a", env={"robots": ["walker_2_main"], "test_robots": []}))
    b = Run(fake_run(tmp_path / "b", env={"robots": ["walker_4_main"], "test_robots": []}))
    assert a.single_robot == "walker_2_main" and a.fingerprint == b.fingerprint
    (group,) = comparable_groups([a, b])
    assert group.label == "gcnt" and [r.single_robot for r in group.runs] == TRAIN
    # the same robot and seed twice is a seed given twice
    again = Run(fake_run(tmp_path / "c", env={"robots": ["walker_2_main"], "test_robots": []}))
    with pytest.raises(AnalysisError, match="both are seed 0 on walker_2_main"):
        comparable_groups([a, b, again])


def test_curves_split_runs_of_other_budgets_naming_the_key(tmp_path, caplog):
    for seed in (0, 1):
        fake_run(tmp_path / "long" / f"seed{seed}", seed, level=10.0)
    fake_run(tmp_path / "short" / "seed0", 0, level=0.0, collector={"total_frames": 1200})
    fake_run(tmp_path / "swat" / "seed0", network={"name": "swat"})
    with caplog.at_level(logging.WARNING, logger="gcnt.analysis.groups"):
        rows = curves.learning_curves(find_runs([tmp_path]))
    assert "collector.total_frames: 2400 vs 1200" in caplog.text
    last = {r["method"]: r for r in rows}
    # each experiment has its own line, its seeds only, at its own steps; the method's place kept
    assert list(last) == [
        "gcnt [collector.total_frames=1200]",
        "gcnt [collector.total_frames=2400]",
        "swat",
    ]
    long = last["gcnt [collector.total_frames=2400]"]
    assert (long["seeds"], long["env_steps"], long["mean"]) == (2, 2400, pytest.approx(10.5))
    short = last["gcnt [collector.total_frames=1200]"]
    assert (short["seeds"], short["env_steps"], short["mean"]) == (1, 1200, 0.0)


def test_a_seed_given_twice_is_refused_naming_both_runs(tmp_path, capsys):
    first = fake_run(tmp_path / "td3-gcnt" / "seed0")
    again = fake_run(tmp_path / "td3-gcnt" / "seed0-1", logger={"backend": "none"})
    runs = find_runs([tmp_path])
    for analyse in (
        lambda: curves.learning_curves(runs),
        lambda: zeroshot.zero_shot_table(runs),
        lambda: variants.variant_summary(runs, ["training"]),
    ):
        with pytest.raises(AnalysisError, match="both are seed 0 of one experiment") as e:
            analyse()
        assert str(first) in str(e.value) and str(again) in str(e.value)
    capsys.readouterr()
    assert main(["curves", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(first) in err and str(again) in err


def test_zeroshot_and_variants_split_experiments_alike(tmp_path):
    for seed in (0, 1):
        fake_run(tmp_path / "random" / f"seed{seed}", seed, level=1.0)
        fake_run(
            tmp_path / "policy" / f"seed{seed}", seed, level=5.0, td3={"init_random_frames": 0}
        )
    runs = find_runs([tmp_path])
    names = ["gcnt [td3.init_random_frames=600]", "gcnt [td3.init_random_frames=0]"]
    table = zeroshot.zero_shot_table(runs)["Walker++"]
    assert table["methods"] == sorted(names)
    cells = table["cells"][TEST[0]]
    assert cells[names[0]]["per_seed"] == {"0": 10.0, "1": 20.0}
    assert cells[names[1]]["per_seed"] == {"0": 50.0, "1": 60.0}
    summary = variants.variant_summary(runs, ["training"], reps=50)["training"]
    assert sorted(summary) == sorted(names)
    assert summary[names[1]]["seeds"] == 2 and summary[names[1]]["mean"]["point"] == 55.0


def test_fine_tunes_of_other_experiments_are_told_apart_by_their_source(tmp_path):
    def fine_tune(name: str, seed: int, fingerprint: str) -> Path:
        record = {"run": f"/runs/src/seed{seed}", "task": "Walker++", "fingerprint": fingerprint}
        return fake_run(
            tmp_path / name / f"seed{seed}",
            seed,
            task="Walker++-ft",
            init_from=f"/runs/src/seed{seed}",
            resolved={"init_from": record},
        )

    # fine-tunes of two seeds of one source experiment: seeds of one fine-tune
    for seed in (0, 1):
        fine_tune("a", seed, "aaaa")
    fine_tune("b", 0, "bbbb")
    groups = comparable_groups(find_runs([tmp_path]))
    assert [(g.label, len(g.runs)) for g in groups] == [
        ("gcnt [init_from.fingerprint=aaaa]", 2),
        ("gcnt [init_from.fingerprint=bbbb]", 1),
    ]
    assert groups[0].runs[1].fine_tune_of == "Walker++ run /runs/src/seed1"


def test_a_fine_tuned_run_keeps_a_task_of_its_own(tmp_path, monkeypatch):
    """Stacked seeds are seeds of one experiment; each fine-tune of one of them goes to
    ``runs/<task>-ft/`` (not beside its source, as ``seed0-1``), and the fine-tunes of both
    seeds are the seeds of one fine-tune."""
    monkeypatch.chdir(tmp_path)
    recipe = str(tiny_td3_recipe(tmp_path / "tiny.yaml"))
    tiny = ["td3.schedule=mixed", "eval.episodes=0", "env.num_threads=1"]
    assert main(["train", recipe, "--seeds", "0,1", *tiny]) == 0
    source = Path("runs/tiny/td3-gcnt")
    short = ["collector.total_frames=10", "td3.init_random_frames=5", "checkpoint_interval=10"]
    for seed in (0, 1):
        argv = ["train", recipe, "--init-from", str(source / f"seed{seed}"), f"seed={seed}"]
        assert main([*argv, "env.robots=[hopper_5]", *tiny, *short]) == 0
    tuned = Path("runs/tiny-ft/td3-gcnt")
    assert sorted(p.name for p in source.iterdir()) == ["seed0", "seed1"]
    assert sorted(p.name for p in tuned.iterdir()) == ["seed0", "seed1"]
    written = yaml.safe_load((tuned / "seed1" / "recipe.yaml").read_text())
    assert written["task"] == "tiny-ft" and written["init_from"] == str(source / "seed1")
    record = written["resolved"]["init_from"]
    assert record["task"] == "tiny" and record["fingerprint"] == Run(source / "seed0").fingerprint
    groups = comparable_groups(find_runs(["runs"]))
    assert [(g.task, g.label, len(g.runs)) for g in groups] == [
        ("tiny", "gcnt", 2),
        ("tiny-ft", "gcnt", 2),
    ]
    assert Run(tuned / "seed0").fine_tune_of == f"tiny run {(source / 'seed0').resolve()}"
    # a recipe that names a task of its own keeps it
    named = load_recipe(recipe, [f"init_from={source / 'seed0'}", "task=mine"])
    own_task(named)
    assert named.task == "mine"


def test_a_sweep_of_fine_tunes_puts_them_under_their_own_task(tmp_path, recipe_file, trained):
    from gcnt import sweep as S

    specs = S.expand(
        [recipe_file], tmp_path / "sw", seeds=[0, 1], overrides=[f"init_from={trained}"]
    )
    assert [s.id for s in specs] == ["tiny-ft/td3-gcnt/seed0", "tiny-ft/td3-gcnt/seed1"]
    assert {s.task for s in specs} == {"tiny-ft"}


def test_a_sweep_of_fine_tunes_from_a_run_not_yet_made_is_set_up(tmp_path, recipe_file, caplog):
    from gcnt import sweep as S

    missing = tmp_path / "later" / "seed0"
    for sweep in ("sw", "again"):  # said once per sweep set up, not once per run
        caplog.clear()
        specs = S.expand(
            [recipe_file], tmp_path / sweep, seeds=[0, 1], overrides=[f"init_from={missing}"]
        )
        assert [s.id for s in specs] == ["tiny/td3-gcnt/seed0", "tiny/td3-gcnt/seed1"]
        assert caplog.text.count("does not exist yet") == 1


def test_a_key_an_older_recipe_lacks_counts_as_its_default(tmp_path):
    from gcnt.analysis.runs import recipe_defaults

    assert recipe_defaults()["td3.target"] == "auto"
    new = Run(fake_run(tmp_path / "new", td3={"target": "auto", "checkpoint_buffers": True}))
    old = Run(fake_run(tmp_path / "old", seed=1))  # written before td3.target existed
    other = Run(fake_run(tmp_path / "other", seed=2, td3={"target": "min"}))
    assert new.fingerprint == old.fingerprint != other.fingerprint
    # settings of methods the run does not train, and workers a single collector does not use
    extra = Run(
        fake_run(
            tmp_path / "extra",
            seed=3,
            network={"method_kwargs": {"smp": {"hidden": 7}}},
            ppo={"workers": 8, "worker_envs": 32, "collector": "single"},
        )
    )
    assert extra.fingerprint == new.fingerprint
    mine = Run(fake_run(tmp_path / "mine", seed=4, network={"method_kwargs": {"gcnt": {"ff": 8}}}))
    assert mine.fingerprint != new.fingerprint


def test_fine_tunes_recorded_without_their_source_fingerprint_are_seeds_of_one(tmp_path):
    sources = [fake_run(tmp_path / "src" / f"seed{s}", seed=s) for s in (0, 1)]
    tunes = [
        Run(
            fake_run(
                tmp_path / "ft" / f"seed{s}",
                seed=s,
                task="Walker++-ft",
                init_from=str(sources[s]),
                resolved={"init_from": {"run": str(sources[s]), "env_steps": 2400}},
            )
        )
        for s in (0, 1)
    ]
    assert tunes[0].fingerprint == tunes[1].fingerprint
    assert [len(g.runs) for g in comparable_groups(tunes)] == [2]
