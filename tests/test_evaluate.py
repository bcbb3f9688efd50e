"""Tests for ``gcnt.rl.evaluate`` and ``gcnt eval``: ``summarize_robots`` gives the mean over
robots with a bootstrap 95% confidence interval around it from 5 robots, below that their range,
each under fields named for it; evaluation and metrics files are strict JSON (non-finite values as ``null``, read
back as NaN); ``gcnt eval`` and the evaluations a sweep runs follow the recipe's
``eval.deterministic`` unless a flag says otherwise.
"""

import pytest

from gcnt.rl.evaluate import summarize_robots


def test_summarize_robots_bootstrap_ci():
    res = {f"r{i}": {"mean": float(m)} for i, m in enumerate([1.0, 2.0, 3.0, 4.0, 10.0])}
    s = summarize_robots(res)
    assert s["mean"] == pytest.approx(4.0) and s["robots"] == 5
    assert s["ci95_low"] < 4.0 < s["ci95_high"]


def test_fewer_robots_than_a_bootstrap_needs_store_their_range_named_so():
    s = summarize_robots({"a": {"mean": 2.0}, "b": {"mean": 5.0}, "c": {"mean": 3.0}})
    assert s == {"mean": pytest.approx(10 / 3), "range_low": 2.0, "range_high": 5.0, "robots": 3}
    one = summarize_robots({"a": {"mean": 2.0}})
    assert (one["range_low"], one["range_high"], "ci95_low" in one) == (2.0, 2.0, False)


def _strict(text: str):
    """json.loads refusing NaN and ±Infinity (what strict JSON readers do)."""
    import json

    return json.loads(text, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))


def test_eval_files_are_strict_json(tmp_path):
    import math

    from gcnt.rl.evaluate import summarize, write_eval

    # one episode: no standard error; it is written as null
    path = write_eval(tmp_path / "step1.json", {"a": summarize([3.0])}, 1, {"episodes": 1})
    data = _strict(path.read_text())
    assert data["robots"]["a"]["stderr"] is None and data["robots"]["a"]["mean"] == 3.0
    assert math.isnan(summarize([3.0])["stderr"])


def test_metrics_are_strict_json_and_read_back_as_nan(tmp_path):
    """A NaN or infinite metric is logged as null; the run's reader (resume) and the analysis
    reader give NaN back; truncating on resume keeps the file strict."""
    import math

    from gcnt.analysis.runs import Run
    from gcnt.run.directory import RunDir

    run = RunDir(tmp_path)
    run.log_metrics({"env_steps": 10, "loss_actor": float("nan"), "x": float("inf"), "y": 1.5})
    run.log_metrics({"env_steps": 20, "loss_actor": 0.5, "nested": [float("-inf")]})
    lines = run.metrics_path.read_text().splitlines()
    assert [_strict(line)["env_steps"] for line in lines] == [10, 20]
    assert _strict(lines[0])["loss_actor"] is None and _strict(lines[0])["x"] is None
    rows = run.read_metrics()
    assert math.isnan(rows[0]["loss_actor"]) and math.isnan(rows[0]["x"]) and rows[0]["y"] == 1.5
    run.truncate_metrics(10)
    assert [_strict(line) for line in run.metrics_path.read_text().splitlines()] == [
        {"env_steps": 10, "loss_actor": None, "x": None, "y": 1.5}
    ]
    (tmp_path / "recipe.yaml").write_text("seed: 0\n")
    assert math.isnan(Run(tmp_path).metrics()[0]["loss_actor"])


def test_what_training_wrote_after_the_checkpoint_is_set_aside_on_resume(tmp_path):
    """Evaluations and videos of steps past the checkpoint go to superseded/ (never over one
    already there), where the analyses do not read them; others stay; a superseded/ that is a
    link is refused and nothing moves."""
    from gcnt.analysis.runs import Run
    from gcnt.run.directory import RunDir, RunDirError

    run = RunDir(tmp_path / "run")
    (run.path / "eval" / "superseded").mkdir(parents=True)
    (run.path / "videos").mkdir()
    (run.path / "recipe.yaml").write_text("seed: 0\n")
    for name in ("step10.json", "step30.json", "test-30.json", "superseded/step30.json"):
        (run.path / "eval" / name).write_text('{"env_steps": 1, "robots": {}}')
    (run.path / "videos" / "step30.mp4").write_bytes(b"video")
    moved = run.set_aside_after(20)
    assert [p.relative_to(run.path).as_posix() for p in moved] == [
        "eval/superseded/step30.1.json",
        "videos/superseded/step30.mp4",
    ]
    assert sorted(p.name for p in (run.path / "eval").glob("*.json")) == [
        "step10.json",
        "test-30.json",
    ]
    assert sorted(e.path.name for e in Run(run.path).evals()) == ["step10.json", "test-30.json"]
    assert run.set_aside_after(20) == []
    outside = tmp_path / "outside"
    outside.mkdir()
    (run.path / "videos" / "superseded").rename(tmp_path / "kept")
    (run.path / "videos" / "superseded").symlink_to(outside)
    (run.path / "videos" / "step40.mp4").write_bytes(b"video")
    with pytest.raises(RunDirError, match="a link"):
        run.set_aside_after(20)
    assert (run.path / "videos" / "step40.mp4").exists() and not any(outside.iterdir())


@pytest.fixture
def stochastic_run(tmp_path):
    """A run directory whose recipe evaluates with sampled actions (as UNIMAL's recipes do)."""
    import torch

    from gcnt.recipes import load_recipe
    from gcnt.run.directory import RunDir

    recipe = load_recipe("recipes/quickstart.yaml", ["eval.deterministic=false"])
    run = RunDir(tmp_path / "run")
    run.create(recipe)
    torch.save({"env_steps": 40, "policy": {"actor": {}}}, run.checkpoint_path)
    return run


@pytest.mark.parametrize(
    ("flags", "deterministic", "episodes", "mode"),
    [
        ([], False, 32, "stoch"),  # the recipe's protocol, ModuMorph's 32 episodes
        (["--deterministic"], True, 100, "det"),
        (["--stochastic", "--episodes", "3"], False, 3, "stoch"),
    ],
)
def test_gcnt_eval_follows_the_recipe_protocol_unless_told(
    stochastic_run, monkeypatch, capsys, flags, deterministic, episodes, mode
):
    import json

    import gcnt.rl.evaluate as E
    from gcnt.cli import main

    asked = {}

    def fake_evaluate(recipe, policy, specs, *, episodes, seed, deterministic):
        asked.update(episodes=episodes, deterministic=deterministic)
        return {"hopper_3": E.summarize([1.0, 2.0])}

    monkeypatch.setattr(E, "evaluate", fake_evaluate)
    assert main(["eval", str(stochastic_run.path), "--robots", "train", *flags]) == 0
    assert asked == {"episodes": episodes, "deterministic": deterministic}
    out = stochastic_run.path / "eval" / f"train-step40-{mode}-seed10000.json"
    meta = json.loads(out.read_text())
    assert (meta["deterministic"], meta["episodes"]) == (deterministic, episodes)
    action = "deterministic" if deterministic else "sampled"
    assert f"{action} actions, {episodes} episodes per robot" in capsys.readouterr().out


def test_sweep_eval_commands_leave_the_protocol_to_the_recipe():
    from gcnt.sweep import RunSpec, eval_command

    spec = RunSpec(
        id="r", run_dir="r", recipe="x.yaml", task="t", algo="td3", method="gcnt", seed=0,
        overrides=[],
    )  # fmt: skip
    argv = eval_command(spec, "test")
    assert argv[-4:] == ["eval", "r", "--robots", "test"]  # no --episodes, no mode flag
    spec.eval_episodes, spec.eval_deterministic = 10, False
    assert eval_command(spec, "test")[-3:] == ["--episodes", "10", "--stochastic"]
