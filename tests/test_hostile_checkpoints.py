"""Tampered checkpoints, of the older two-critic layout (``tests/data/td3_run_b52e8ec``) and of
today's: NaN weights, parts of the wrong type, tensors of the wrong shape. ``gcnt eval``,
``gcnt train --resume`` and ``--init-from`` each refuse them in one line naming the file and
what is wrong (exit 2), and the run is left as it was."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import torch
from cli_helpers import error_line

FIXTURE = Path(__file__).parent / "data" / "td3_run_b52e8ec"


def _nan_actor(state: dict) -> str:
    for part in (state["policy"]["actor"], state["learner"]["actor"]):
        name = next(k for k, v in part.items() if v.is_floating_point())
        part[name] = torch.full_like(part[name], float("nan"))
    return "holds NaN or infinite values"


def _critics_not_a_mapping(state: dict) -> str:
    state["learner"]["critics"] = 5
    return "does not fit"


def _critic_of_another_shape(state: dict) -> str:
    critics = state["learner"]["critics"]
    name = next(k for k, v in critics.items() if v.dim() == 2)
    critics[name] = torch.zeros(critics[name].shape[0] + 3, 2)
    return "does not fit"


def _learner_a_list(state: dict) -> str:
    state["learner"] = [1, 2]
    return "learner is list, not a mapping"


def _policy_of_another_type(state: dict) -> str:
    state["policy"]["actor"] = "weights"
    return "does not fit"


TAMPERS = {
    "nan": _nan_actor,
    "critics-type": _critics_not_a_mapping,
    "critic-shape": _critic_of_another_shape,
    "learner-type": _learner_a_list,
    "policy-type": _policy_of_another_type,
}
#: the commands that read each part (eval reads the policy only)
READ_BY = {
    "nan": ("eval", "resume", "init-from"),
    "critics-type": ("resume", "init-from"),
    "critic-shape": ("resume", "init-from"),
    "learner-type": ("eval", "resume", "init-from"),
    "policy-type": ("eval",),
}


def _tampered(source: Path, tmp_path: Path, tamper) -> tuple[Path, str]:
    run = tmp_path / "tampered"
    shutil.copytree(source, run)
    path = run / "checkpoints" / "last.pt"
    state = torch.load(path, weights_only=False)
    said = tamper(state)
    torch.save(state, path)
    return run, said


@pytest.mark.parametrize("layout", ["two-critics", "ensemble"])
@pytest.mark.parametrize("case", list(TAMPERS))
def test_a_tampered_checkpoint_is_one_line_naming_it(layout, case, trained, tmp_path, capsys):
    source = FIXTURE if layout == "two-critics" else trained
    run, said = _tampered(source, tmp_path, TAMPERS[case])
    checkpoint = run / "checkpoints" / "last.pt"
    before = checkpoint.read_bytes()
    argvs = {
        "eval": ["eval", str(run), "--episodes", "1", "--robots", "train"],
        "resume": ["train", "--resume", str(run), "collector.total_frames=100"],
        "init-from": [
            "train",
            str(run / "recipe.yaml"),
            "--init-from",
            str(run),
            f"run_dir={tmp_path / 'new'}",
        ],
    }
    for command in READ_BY[case]:
        line = error_line(capsys, argvs[command])
        assert str(checkpoint) in line and said in line, (command, line)
        assert not (tmp_path / "new").exists()
    assert checkpoint.read_bytes() == before
