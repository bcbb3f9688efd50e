"""What a shared run directory, a careless recipe or an unlucky machine can do, and what gcnt
does instead: checkpoints load without running code, a failed write keeps the last good file
and says so in one line, a torn metrics line is dropped, evaluation files never collide,
recipes cannot make gcnt read without bound, sizes that cannot fit are refused before a run
starts, and `gcnt zeroshot` prefers a `gcnt eval --robots test` evaluation on a tie."""

from __future__ import annotations

import errno
import json
import logging
import os
import random
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from cli_helpers import error_line

from gcnt.cli import main as gcnt
from gcnt.morphology import morphologies_dir
from gcnt.recipes import RecipeError, load_recipe
from gcnt.run.directory import (
    CheckpointError,
    RunDir,
    RunDirError,
    plain_state,
    rng_state,
    set_rng_state,
)

ROOT = Path(__file__).parents[1]


def copy_run(run: Path, tmp_path: Path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(run, out)
    return out


# ------------------------------------------------------------------ safe checkpoint loading


class _Payload:
    """Unpickling it creates a marker file (what a crafted checkpoint could do instead)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.mkdir, (str(self.marker),))


def test_a_crafted_checkpoint_does_not_run_and_is_refused_in_one_line(trained, tmp_path, capsys):
    run = copy_run(trained, tmp_path)
    marker = tmp_path / "pwned"
    torch.save({"env_steps": 40, "policy": _Payload(marker)}, run / "checkpoints" / "last.pt")
    with pytest.raises(CheckpointError, match="refused: loading it would call posix.mkdir"):
        RunDir(run).load_checkpoint()
    for argv in (["eval", str(run), "--episodes", "1"], ["train", "--resume", str(run)]):
        line = error_line(capsys, argv)
        assert "last.pt: refused" in line, line
    assert not marker.exists()


def test_checkpoints_hold_only_tensors_and_plain_types_and_resume_the_random_state(tmp_path):
    run = RunDir(tmp_path / "run")
    torch.manual_seed(3), np.random.seed(3), random.seed(3)
    sampler = {"probs": np.array([0.25, 0.75]), "count": np.float64(2.5), "n": np.int64(4)}
    run.save_checkpoint({"env_steps": 7, "sampler": sampler})
    saved = rng_state()
    expected = (torch.rand(3), np.random.rand(3), random.random())
    # torch's own safe loader reads it, with no allow-list
    state = torch.load(run.checkpoint_path, weights_only=True)
    assert isinstance(state["rng"]["numpy"][1], torch.Tensor)
    assert torch.equal(state["sampler"]["probs"], torch.tensor([0.25, 0.75], dtype=torch.float64))
    assert state["sampler"]["count"] == 2.5 and type(state["sampler"]["n"]) is int
    set_rng_state(run.load_checkpoint()["rng"])
    again = (torch.rand(3), np.random.rand(3), random.random())
    assert torch.equal(again[0], expected[0]) and np.array_equal(again[1], expected[1])
    assert again[2] == expected[2]
    assert np.array_equal(np.random.get_state()[1], rng_state()["numpy"][1])
    del saved


def test_a_checkpoint_holding_numpy_arrays_still_loads(tmp_path):
    """Checkpoints written with the RNG state as NumPy objects (NumPy's array reconstruction is
    the only code allowed)."""
    run = RunDir(tmp_path / "run")
    run.checkpoint_path.parent.mkdir(parents=True)
    torch.save({"env_steps": 3, "rng": rng_state(), "x": np.float32(1.5)}, run.checkpoint_path)
    state = run.load_checkpoint()
    assert state["env_steps"] == 3 and state["x"] == 1.5
    set_rng_state(state["rng"])


def test_plain_state_keeps_containers_and_tensors():
    from collections import OrderedDict

    t = torch.ones(2)
    out = plain_state({"a": OrderedDict(w=t), "b": (np.arange(3), [np.bool_(True)]), "c": "x"})
    assert isinstance(out["a"], OrderedDict) and out["a"]["w"] is t
    assert isinstance(out["b"], tuple) and torch.equal(out["b"][0], torch.arange(3))
    assert out["b"][1] == [True] and type(out["b"][1][0]) is bool and out["c"] == "x"


# ------------------------------------------------------------------ failed writes


@pytest.mark.parametrize(
    "error",
    [OSError(errno.ENOSPC, "No space left on device"), RuntimeError("PytorchStreamWriter failed")],
)
def test_a_failed_checkpoint_write_keeps_the_last_one_and_leaves_no_temp_file(
    tmp_path, monkeypatch, error
):
    run = RunDir(tmp_path / "run")
    run.save_checkpoint({"env_steps": 1})
    good = run.checkpoint_path.read_bytes()

    def full_disk(obj, f, *args, **kwargs):  # into the writer's temporary file
        f.write(b"partial")
        raise error

    monkeypatch.setattr(torch, "save", full_disk)
    with pytest.raises(RunDirError) as e:
        run.save_checkpoint({"env_steps": 2})
    message = str(e.value)
    assert "\n" not in message and "cannot write the checkpoint" in message
    assert "the last good checkpoint" in message
    assert run.checkpoint_path.read_bytes() == good
    assert list(run.checkpoint_path.parent.iterdir()) == [run.checkpoint_path]


def test_a_full_disk_while_training_is_one_line(recipe_file, tmp_path, capsys, monkeypatch):
    save = torch.save
    calls = []

    def fails_the_second_time(obj, path, *args, **kwargs):
        calls.append(path)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return save(obj, path, *args, **kwargs)

    monkeypatch.setattr(torch, "save", fails_the_second_time)
    run = tmp_path / "run"
    line = error_line(capsys, ["train", str(recipe_file), f"run_dir={run}"])
    assert "No space left on device" in line and "last good checkpoint" in line
    monkeypatch.setattr(torch, "save", save)
    assert RunDir(run).load_checkpoint()["env_steps"] == 20
    assert not list((run / "checkpoints").glob(".tmp-*"))  # the writer's temporary file


def _read_only(monkeypatch, run: Path) -> None:
    """Writes under ``run`` fail as in a read-only directory (root ignores chmod): the guarded
    writer cannot create its files there."""
    import gcnt.files

    for name in ("_create_temp", "_open_existing_or_new"):
        real = getattr(gcnt.files, name)

        def refuse(path, *args, real=real, **kwargs):
            if str(path).startswith(str(run)):
                raise OSError(errno.EROFS, "Read-only file system", str(path))
            return real(path, *args, **kwargs)

        monkeypatch.setattr(gcnt.files, name, refuse)


def test_eval_of_a_read_only_run_still_writes_json_elsewhere(
    trained, tmp_path, capsys, monkeypatch
):
    run = copy_run(trained, tmp_path)
    before = sorted(p.name for p in (run / "eval").iterdir())
    _read_only(monkeypatch, run)
    line = error_line(capsys, ["eval", str(run), "--episodes", "1"])
    assert "cannot write the evaluation (Read-only file system)" in line
    out = tmp_path / "out" / "result.json"
    assert gcnt(["eval", str(run), "--episodes", "1", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["robots"]["hopper_4"]["episodes"] == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert [line for line in err.splitlines() if "WARNING" in line and "results were" in line]
    assert sorted(p.name for p in (run / "eval").iterdir()) == before  # no temporary file


# ------------------------------------------------------------------ metrics.jsonl


def _metrics(run: Path, text: str) -> Path:
    """A run directory (a recipe, no checkpoint) whose ``metrics.jsonl`` is ``text``."""
    run.mkdir(parents=True, exist_ok=True)
    (run / "recipe.yaml").write_text("task: tiny\nenv: {robots: [hopper_3]}\n")
    (run / "metrics.jsonl").write_text(text)
    return run


class _Records(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


def test_a_torn_last_metrics_line_is_dropped_with_one_warning_by_every_reader(tmp_path):
    from gcnt.analysis.runs import Run

    run = _metrics(tmp_path / "run", '{"env_steps": 10}\n{"env_steps": 20}\n{"env_st')
    records = _Records()
    logger = logging.getLogger("gcnt.run.metrics")
    logger.addHandler(records)
    try:
        assert [r["env_steps"] for r in RunDir(run).read_metrics()] == [10, 20]
        assert [r["env_steps"] for r in Run(run).metrics()] == [10, 20]
    finally:
        logger.removeHandler(records)
    assert len(records.messages) == 1 and "line 3 is incomplete" in records.messages[0]


def test_a_damaged_metrics_line_before_the_last_names_file_and_line(tmp_path):
    from gcnt.analysis.runs import AnalysisError, Run

    run = _metrics(tmp_path / "run", '{"env_steps": 10}\n{"env_st\n{"env_steps": 30}\n')
    with pytest.raises(RunDirError, match=r"metrics.jsonl, line 2: not a metrics row"):
        RunDir(run).read_metrics()
    with pytest.raises(AnalysisError, match=r"metrics.jsonl, line 2"):
        Run(run).metrics()


def test_resume_after_a_torn_metrics_line(trained, tmp_path):
    run = copy_run(trained, tmp_path)
    rows = RunDir(run).read_metrics()
    with (run / "metrics.jsonl").open("a") as f:
        f.write('{"env_steps": 6')
    assert gcnt(["train", "--resume", str(run), "collector.total_frames=60"]) == 0
    after = RunDir(run).read_metrics()
    assert after[: len(rows)] == rows and after[-1]["env_steps"] == 60
    assert all(line.startswith("{") for line in (run / "metrics.jsonl").read_text().splitlines())


# ------------------------------------------------------------------ evaluation file names


def test_evaluation_file_names_never_collide_for_different_robot_sets():
    from gcnt.commands.eval import _label

    assert _label(["a b.xml"]) != _label(["a_b.xml"])
    assert _label(["x/hopper.xml"]) != _label(["y/hopper.xml"])
    assert _label(["a", "b"]) != _label(["a+b.xml"])
    long = [f"robot_{i:03d}" for i in range(20)]
    assert _label(long) != _label([*long[:-1], "robot_999"])
    # exact names stay readable, as the analysis commands match them
    assert _label(["test"]) == "test" and _label(["hopper_3"]) == "hopper_3"
    assert _label(["Unimal:variants-kinematics"]) == "Unimal-variants-kinematics"


# ------------------------------------------------------------------ recipes


def _recipe(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "r.yaml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    ("base", "message"),
    [
        ("/dev/zero", "not a regular file"),
        ("5", "base: expected the path of a recipe file, got int"),
        ("[a, b]", "base: expected the path of a recipe file, got list"),
        ("''", "got an empty string"),
    ],
)
def test_a_base_must_name_a_regular_recipe_file(tmp_path, base, message):
    with pytest.raises(RecipeError, match=message):
        load_recipe(_recipe(tmp_path, f"base: {base}\n"))


def test_a_base_that_is_a_directory_fifo_or_huge_file_is_refused(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    huge = tmp_path / "huge.yaml"
    huge.write_bytes(b"#" * (2 << 20))
    for base, message in ((tmp_path, "a directory"), (fifo, "not a regular file"),
                          (huge, "larger than 1.0 MiB")):  # fmt: skip
        with pytest.raises(RecipeError, match=message):
            load_recipe(_recipe(tmp_path, f"base: {base}\n"))


def test_an_error_never_quotes_a_file_that_is_not_a_recipe(tmp_path):
    secret = tmp_path / "shadow"
    secret.write_text("root:$y$j9T$SECRETHASH:19000:0:99999:7:::\nTOKEN: SECRETVALUE\n")
    binary = tmp_path / "blob"
    binary.write_bytes(bytes(range(256)) * 4)
    for path in (secret, binary):
        for recipe in (path, _recipe(tmp_path, f"base: {path}\n")):
            with pytest.raises(RecipeError) as e:
                load_recipe(recipe)
            message = str(e.value)
            assert str(path) in message and "SECRET" not in message, message


def test_yaml_aliases_cannot_expand_without_bound(tmp_path):
    levels = ["a: &a [x, x, x, x, x, x, x, x, x, x]"]
    for i, name in enumerate("bcdefgh"):
        prev = "abcdefgh"[i]
        levels.append(f"{name}: &{name} [{', '.join(['*' + prev] * 10)}]")
    bomb = _recipe(tmp_path, "\n".join(levels) + "\nenv: {robots: *h}\n")
    with pytest.raises(RecipeError, match="aliases expand to more than"):
        load_recipe(bomb)
    with pytest.raises(RecipeError, match="refers to the value that contains it"):
        load_recipe(_recipe(tmp_path, "env: &e {robots: [hopper_3], x: *e}\n"))
    # a few aliases (PyYAML writes them for repeated values) are fine
    ok = _recipe(tmp_path, "env: {robots: &r [hopper_3], test_robots: *r}\n")
    assert load_recipe(ok).env.test_robots == ["hopper_3"]


# ------------------------------------------------------------------ memory


def test_a_replay_that_cannot_fit_is_refused_before_the_run_directory(
    recipe_file, tmp_path, capsys
):
    run = tmp_path / "run"
    line = error_line(
        capsys,
        [
            "train",
            str(recipe_file),
            f"run_dir={run}",
            "td3.buffer_size_per_robot=1000000000000",
            "td3.buffer_total_size=1000000000000",
        ],
    )
    assert "the replay (1 robots x 1000000000000 transitions" in line
    assert "td3.buffer_size_per_robot" in line
    assert not run.exists()


def test_check_memory_compares_with_the_machine():
    from gcnt.rl.config_check import check_memory, memory_bytes

    have = memory_bytes("cpu")
    assert have is not None and have > 0
    check_memory(have // 2, "cpu", "x", "fix")
    with pytest.raises(
        RecipeError, match="more than .*: (the memory of this machine|this job's memory limit)"
    ):
        check_memory(have + 1, "cpu", "x", "fix")


def test_the_memory_check_names_the_address_space_limit_when_that_is_the_limit():
    import resource
    import subprocess
    import sys

    limit = 6 << 30

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    code = (
        "from gcnt.rl.config_check import check_memory\n"
        "try:\n    check_memory(8 << 30, 'cpu', 'the replay', 'lower it')\n"
        "except ValueError as e:\n    print(e)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], preexec_fn=cap, capture_output=True, text=True, check=True
    ).stdout
    assert "address-space limit (ulimit -v, 6.4 GB)" in out and "this machine" not in out, out
    assert out.strip().endswith("; lower it")


def test_a_robot_too_large_for_the_mujoco_arena_is_one_line(trained, tmp_path, capsys):
    xml = (morphologies_dir() / "smpenv" / "hopper_3.xml").read_text()
    assert "<option " in xml
    robot = tmp_path / "hopper_small_arena.xml"
    robot.write_text(xml.replace("<option ", '<size memory="1K"/>\n  <option ', 1))
    run = copy_run(trained, tmp_path)
    line = error_line(capsys, ["eval", str(run), "--robots", str(robot), "--episodes", "1"])
    assert "robot 'hopper_small_arena'" in line and "arena" in line
    assert '<size memory="2K"/>' in line


# ------------------------------------------------------------------ zero-shot


def test_zeroshot_prefers_gcnt_eval_of_the_test_robots_on_a_tie(tmp_path):
    """Training's final evaluation of one ``Benchmark:test`` spec also names ``test``; the
    `gcnt eval --robots test` evaluation still wins when steps, protocol and episodes tie."""
    from gcnt.analysis.runs import EvalRecord
    from gcnt.analysis.zeroshot import seed_score

    def record(name: str, spec: str, mean: float) -> EvalRecord:
        label = "" if name.startswith("step") else name.split("-step")[0]
        robots = {"walker_3_main": {"mean": mean, "episodes": 5}}
        meta = {"robots_spec": [spec], "deterministic": True}
        return EvalRecord(tmp_path / f"{name}.json", label, 100, robots, meta)

    training = record("step100", "Walker++:test", 1.0)
    test = record("test-step100-det-seed10000", "test", 2.0)
    assert training.matches("test")  # both name the test set
    for evals in ([training, test], [test, training]):
        assert seed_score(evals, "walker_3_main", deterministic=True) == (2.0, test)


def test_the_same_relative_robot_path_from_two_folders_names_two_files(tmp_path, monkeypatch):
    """``--robots r/x.xml`` typed in two working folders names two different robots: the file
    name hashes the resolved file and its content, and the JSON records them."""
    from gcnt.commands.eval import _label, resolved_spec

    names, resolved = [], []
    for folder, text in (("one", "<mujoco model='a'/>"), ("two", "<mujoco model='b'/>")):
        (tmp_path / folder / "r").mkdir(parents=True)
        (tmp_path / folder / "r" / "x.xml").write_text(text)
        monkeypatch.chdir(tmp_path / folder)
        resolved.append(resolved_spec("r/x.xml"))
        names.append(_label(["r/x.xml"], [resolved[-1]]))
    assert names[0] != names[1]
    assert resolved[0].startswith(str(tmp_path / "one" / "r" / "x.xml") + "#")
    # the same file, edited in place, is another robot too
    (tmp_path / "two" / "r" / "x.xml").write_text("<mujoco model='c'/>")
    assert resolved_spec("r/x.xml") != resolved[1]
    # names and catalogue specs are not paths: kept as typed
    assert resolved_spec("hopper_3") == "hopper_3"
    assert resolved_spec("Unimal:variants-kinematics") == "Unimal:variants-kinematics"


def test_memory_counts_the_address_space_limit():
    """Under ``ulimit -v`` (RLIMIT_AS) a run may use the limit minus what it has mapped (torch
    and its libraries), however much the machine has."""
    import resource
    import subprocess
    import sys

    limit = 6 << 30

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    code = "from gcnt.rl.config_check import memory_bytes; print(memory_bytes('cpu'))"
    out = subprocess.run(
        [sys.executable, "-c", code], preexec_fn=cap, capture_output=True, text=True, check=True
    )
    assert 0 < int(out.stdout) < limit


def test_a_base_through_a_symlink_loop_is_one_line(tmp_path):
    (tmp_path / "b.yaml").symlink_to(tmp_path / "a.yaml")
    (tmp_path / "a.yaml").symlink_to(tmp_path / "b.yaml")
    with pytest.raises(RecipeError, match=r"a\.yaml: cannot be resolved"):
        load_recipe(_recipe(tmp_path, "base: a.yaml\n"))
