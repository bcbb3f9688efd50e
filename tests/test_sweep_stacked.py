"""``gcnt sweep --stack-seeds``: the seeds of one TD3 experiment train in one process
(``gcnt train --seeds``), each into the directory the sweep gave it, then evaluate one by one;
runs that cannot stack (begun already, the paper schedule, PPO, a refused start) train alone."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from cli_helpers import TINY_SWEEP_OVERRIDES

from gcnt import sweep as S
from gcnt.analysis.runs import find_runs
from gcnt.cli import main
from gcnt.sweep import local

ROOT = Path(__file__).resolve().parents[1]
QUICKSTART = ROOT / "recipes" / "quickstart.yaml"  # the mixed schedule
TINY = [*TINY_SWEEP_OVERRIDES, "logger.backend=none"]


def _ids(groups) -> list[list[str]]:
    return [[s.id for s in g] for g in groups]


def test_the_seeds_of_each_method_form_one_group(tmp_path: Path) -> None:
    specs = S.expand(
        [QUICKSTART],
        tmp_path / "sw",
        methods=["gcnt", "mlp"],
        seeds=[0, 1, 2],
        overrides=[*TINY, "mlp:env.test_robots=[]"],  # SR's MLP takes no larger robot
    )
    groups = local.stacked_groups(specs, True)
    assert _ids(groups) == [
        [f"quickstart/td3-gcnt/seed{s}" for s in (0, 1, 2)],
        [f"quickstart/td3-mlp/seed{s}" for s in (0, 1, 2)],
    ]
    argv = local.stacked_command(groups[0])
    assert argv[argv.index("--seeds") + 1] == "0,1,2"
    assert f"run_dir={tmp_path.resolve() / 'sw/quickstart/td3-gcnt'}" in argv
    assert not [a for a in argv if a.startswith(("seed=", "logger.name="))]
    # off, or by default on a CPU: every run alone
    assert all(len(g) == 1 for g in local.stacked_groups(specs, False))
    assert all(len(g) == 1 for g in local.stacked_groups(specs, None))
    # a run begun already continues alone; the others still stack
    Path(specs[1].run_dir).mkdir(parents=True)
    Path(specs[1].run_dir, "recipe.yaml").write_text("task: x\n")
    assert _ids(local.stacked_groups(specs[:3], True)) == [
        ["quickstart/td3-gcnt/seed0", "quickstart/td3-gcnt/seed2"],
        ["quickstart/td3-gcnt/seed1"],
    ]


def test_the_paper_schedule_and_ppo_do_not_stack(tmp_path: Path, caplog) -> None:
    specs = S.expand(
        [QUICKSTART], tmp_path / "p", seeds=[0, 1], overrides=[*TINY, "td3.schedule=paper"]
    )
    assert all(len(g) == 1 for g in local.stacked_groups(specs, True))
    assert "stacked seeds need td3.schedule=mixed" in caplog.text
    ppo = S.expand([ROOT / "recipes/unimal/quickstart.yaml"], tmp_path / "q", seeds=[0, 1])
    assert all(len(g) == 1 for g in local.stacked_groups(ppo, True))


@pytest.mark.slow
def test_a_stacked_sweep_trains_the_seeds_in_one_process_then_evaluates_each(
    tmp_path: Path,
) -> None:
    sw = tmp_path / "sw"
    argv = ["sweep", str(QUICKSTART), "--seeds", "0,1", "--dir", str(sw), "--stack-seeds", *TINY]
    assert main([*argv, "--eval", "test", "--episodes", "1"]) == 0
    manifest = json.loads((sw / S.MANIFEST).read_text())
    assert [r["state"] for r in manifest["runs"]] == ["done", "done"]
    assert all(r["eval_state"] == {"test": "done"} for r in manifest["runs"])
    runs = find_runs([sw])
    assert [r.seed for r in runs] == [0, 1] and all(r.finished() for r in runs)
    assert [r.path for r in runs] == [Path(r.run_dir) for r in S.Manifest.load(sw).runs]
    # one training process for both seeds (in seed 0's log), then an evaluation per seed
    logs = "".join(p.read_text() for p in sorted((sw / "logs").iterdir()))
    starts = [line for line in logs.splitlines() if line.startswith("# ")]
    assert [line for line in starts if " train " in line][0].endswith("--seeds 0,1")
    assert len([line for line in starts if " train " in line]) == 1
    assert len([line for line in starts if " eval " in line]) == 2
    assert all(any("hopper_4" in e.robots for e in r.evals()) for r in runs)


@pytest.mark.slow
def test_a_refused_stacked_start_trains_the_seeds_one_by_one(tmp_path: Path, monkeypatch) -> None:
    # a stacked start that exits with an error before making any run directory
    monkeypatch.setattr(
        local, "stacked_command", lambda group: [sys.executable, "-c", "raise SystemExit(2)"]
    )
    sw = tmp_path / "sw"
    argv = ["sweep", str(QUICKSTART), "--seeds", "0,1", "--dir", str(sw), "--stack-seeds", *TINY]
    assert main(argv) == 0
    manifest = S.Manifest.load(sw)
    assert [r.state for r in manifest.runs] == ["done", "done"]
    assert all(Path(r.run_dir, "metrics.jsonl").is_file() for r in manifest.runs)


def test_stack_seeds_is_refused_with_slurm(tmp_path: Path, capsys) -> None:
    argv = ["sweep", str(QUICKSTART), "--dir", str(tmp_path / "s"), "--slurm", "--stack-seeds"]
    assert main([*argv, *TINY]) == 2
    assert "--stack-seeds runs in the local pool" in capsys.readouterr().err


def test_a_stopped_stacked_start_is_not_restarted_one_by_one(tmp_path: Path, monkeypatch) -> None:
    from gcnt.rl.stop import EXIT_STOPPED

    # stopped on request (or killed) before any run directory: left for the next sweep
    argv = [sys.executable, "-c", f"raise SystemExit({EXIT_STOPPED})"]
    monkeypatch.setattr(local, "stacked_command", lambda group: argv)
    sw = tmp_path / "sw"
    main(["sweep", str(QUICKSTART), "--seeds", "0,1", "--dir", str(sw), "--stack-seeds", *TINY])
    runs = S.Manifest.load(sw).runs
    assert [r.state for r in runs] == ["pending", "pending"]
    assert not any(Path(r.run_dir).exists() for r in runs)
