"""On a CUDA device, or on the emulated GPU of ``tests/cuda_emulation`` where there is none:
every TD3 method in both schedules and every accelerator switch, and every PPO method on UNIMAL,
trains, checkpoints (CPU tensors), resumes and evaluates with ``device=cuda``, then resumes and
evaluates on the CPU; a CPU run resumes on the GPU with CUDA graphs. Tiny sizes: what is checked
is placement and capture, not learning.

``make test`` runs a subset (each method family, eager and graphed, both schedules, stacked
seeds, the collector's graphed policy, moves both ways); the rest is marked ``gpu_matrix`` and
runs with ``--gpu-matrix`` (``make test-gpu-emulated``, or ``pytest -m gpu --gpu-matrix`` on a
GPU machine)."""

from __future__ import annotations

import itertools
import json

import pytest
import torch
import yaml
from cli_helpers import tiny_td3_recipe

from gcnt.cli import main as gcnt
from gcnt.recipes import CompileConfig

pytestmark = [pytest.mark.gpu]
MATRIX = pytest.mark.gpu_matrix

TD3_METHODS = (
    "gcnt",
    "gcnt_no_gcn",
    "gcnt_no_wl",
    "gcnt_no_dist",
    "gcnt_dist_first",
    "amorpheus",
    "swat",
    "smp",
    "mlp",
)
#: network sizes per method that the tiny recipes use (the Transformer's are the recipe's)
SMALL = {
    "smp": {"msg_dim": 8, "hidden": 12, "head_hidden": [16]},
    "mlp": {"hidden": [32, 32]},
    "sr": {"hidden": [32, 32]},
}
#: methods whose network is built for one limb count: no zero-shot robot (they evaluate the
#: robot they train on)
FIXED_SIZE = {"mlp"}
SWITCHES = {
    "eager": [],
    "compile": ["compile.compile=true"],
    "cudagraphs": ["compile.cudagraphs=true", "compile.replay_on_device=true"],
    "compile+cudagraphs": [
        "compile.compile=true",
        "compile.cudagraphs=true",
        "compile.replay_on_device=true",
    ],
    "amp": ["compile.amp=true"],
    "policy_cudagraphs": ["compile.policy_cudagraphs=true"],
}
GRAPHED = {"cudagraphs", "compile+cudagraphs", "policy_cudagraphs"}


def cases(*axes, subset) -> list:
    """Every combination of ``axes``; those outside ``subset`` marked gpu_matrix."""
    return [pytest.param(*c, marks=() if subset(*c) else MATRIX) for c in itertools.product(*axes)]


def _all_cpu(path) -> bool:
    state = torch.load(path, weights_only=True)  # as written: no map_location
    stack, ok = [state], True
    while stack:
        x = stack.pop()
        if isinstance(x, torch.Tensor):
            ok &= x.device.type == "cpu"
        elif isinstance(x, dict):
            stack.extend(x.values())
        elif isinstance(x, (list, tuple)):
            stack.extend(x)
    return ok


class Replays:
    """Counts the CUDA graph replays in a block (on the emulated GPU; unchecked on a real one,
    where ``torch.cuda.CUDAGraph.replay`` is a C++ method)."""

    def __enter__(self):
        from cuda_emulation import active, graphs

        self.emulated = active()
        self.graphs = graphs
        self.before = graphs.counts["replays"]
        return self

    def __exit__(self, *exc):
        self.n = self.graphs.counts["replays"] - self.before
        return False

    def check(self, graphed: bool) -> None:
        if self.emulated:
            assert (self.n > 0) == graphed, f"{self.n} CUDA graph replays"


def _dropped_line(err: str, overrides: list[str]) -> None:
    """The one warning line of a CPU resume that drops the run's CUDA-only switches (none
    when it had none)."""
    said = [line for line in err.splitlines() if "CUDA only" in line]
    dropped = [k for k in CompileConfig.CUDA_ONLY if f"compile.{k}=true" in overrides]
    if not dropped:
        assert not said, said
        return
    assert len(said) == 1, err
    assert "continuing on cpu without" in said[0], said
    for key in dropped:
        assert f"compile.{key}" in said[0], said


def _train_resume_eval(capsys, tmp_path, recipe, overrides: list[str], frames=(80, 120)) -> None:
    """train -> checkpoint (CPU tensors) -> resume to ``frames[0]`` steps -> eval, all on cuda,
    then resume on the CPU to ``frames[1]`` (without the CUDA-only switches, in one line) and
    evaluate there."""
    run = tmp_path / "run"
    graphed = any(o.split("=")[0] in ("compile.cudagraphs", "compile.policy_cudagraphs")
                  and o.endswith("=true") for o in overrides)  # fmt: skip
    capsys.readouterr()
    with Replays() as replays:
        code = gcnt(["train", str(recipe), "device=cuda", f"run_dir={run}", *overrides])
        assert code == 0, capsys.readouterr().err
        ckpt = run / "checkpoints" / "last.pt"
        assert _all_cpu(ckpt)
        assert gcnt(["train", "--resume", str(run), f"collector.total_frames={frames[0]}"]) == 0
    replays.check(graphed)
    assert _all_cpu(ckpt)
    out = tmp_path / "eval.json"
    assert gcnt(["eval", str(run), "--robots", "train", "--episodes", "1", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["robots"]
    # a run trained on the GPU resumes and evaluates on the CPU
    capsys.readouterr()
    cpu = ["train", "--resume", str(run), "device=cpu", f"collector.total_frames={frames[1]}"]
    assert gcnt(cpu) == 0
    _dropped_line(capsys.readouterr().err, overrides)
    assert yaml.safe_load((run / "recipe.yaml").read_text())["device"] == "cpu"
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert rows[-1]["env_steps"] == frames[1]
    assert gcnt(["eval", str(run), "--robots", "train", "--episodes", "1"]) == 0


def _td3_recipe(tmp_path, method):
    robots = () if method in FIXED_SIZE else ("hopper_4",)
    return tiny_td3_recipe(tmp_path / "tiny.yaml", test_robots=robots)


@pytest.mark.parametrize(
    ("method", "schedule"),
    cases(TD3_METHODS, ["paper", "mixed"], subset=lambda m, s: False),
)
def test_td3_method_on_cuda(capsys, tmp_path, method, schedule):
    over = [f"network.name={method}", f"td3.schedule={schedule}"]
    if method in SMALL:
        over.append(f"network.kwargs={json.dumps(SMALL[method])}")
    _train_resume_eval(capsys, tmp_path, _td3_recipe(tmp_path, method), over)


def _in_make_test(method, switch, schedule) -> bool:
    if switch == "policy_cudagraphs":
        return method == "gcnt" and schedule == "mixed"
    return switch in ("eager", "cudagraphs")


@pytest.mark.parametrize(
    ("method", "switch", "schedule"),
    cases(["gcnt", "smp"], list(SWITCHES), ["paper", "mixed"], subset=_in_make_test),
)
def test_td3_switches_on_cuda(capsys, tmp_path, method, switch, schedule):
    over = [f"network.name={method}", f"td3.schedule={schedule}", *SWITCHES[switch]]
    if method in SMALL:
        over.append(f"network.kwargs={json.dumps(SMALL[method])}")
    _train_resume_eval(capsys, tmp_path, _td3_recipe(tmp_path, method), over)


@pytest.mark.parametrize(
    "method",
    cases(
        ["metamorph", "metamorph_star", "modumorph", "gcnt", "gcnt_hn", "sr"],
        subset=lambda m: m in ("gcnt", "sr"),
    ),
)
def test_ppo_method_on_cuda(capsys, tmp_path, method):
    from test_ppo import tiny_recipe

    d = tiny_recipe(tmp_path / "unused", "unimal").to_dict()
    d.pop("run_dir", None)
    d["network"]["name"] = method
    if method in SMALL:
        d["network"]["kwargs"] = SMALL[method]
        d["env"]["max_limbs"] = 12  # SR's input size is fixed by the padding
        d["env"]["robots"] = d["env"]["robots"][:1]
    path = tmp_path / "ppo.yaml"
    path.write_text(yaml.safe_dump(d))
    _train_resume_eval(capsys, tmp_path, path, [], frames=(320, 400))


@pytest.mark.parametrize(
    "switch", cases(list(SWITCHES), subset=lambda s: s in ("eager", "cudagraphs"))
)
def test_stacked_seeds_on_cuda(capsys, tmp_path, switch):
    """``gcnt train --seeds 0,1`` (one vmapped update for both seeds) on cuda under each switch:
    both runs finish with CPU checkpoints and evaluate."""
    recipe = tiny_td3_recipe(tmp_path / "tiny.yaml")
    base = tmp_path / "seeds"
    argv = ["train", str(recipe), "--seeds", "0,1", "device=cuda", f"run_dir={base}"]
    with Replays() as replays:
        code = gcnt([*argv, "td3.schedule=mixed", *SWITCHES[switch]])
    assert code == 0, capsys.readouterr().err
    replays.check(switch in GRAPHED)
    for seed in (0, 1):
        run = base / f"seed{seed}"
        assert _all_cpu(run / "checkpoints" / "last.pt")
        assert gcnt(["eval", str(run), "--robots", "train", "--episodes", "1"]) == 0


@pytest.mark.parametrize("schedule", cases(["paper", "mixed"], subset=lambda s: s == "mixed"))
def test_a_cpu_run_resumes_on_cuda_with_cuda_graphs(capsys, tmp_path, schedule):
    """A run trained on the CPU (fused Adam, CPU replay) goes on on the GPU, its optimiser
    state captured in CUDA graphs."""
    recipe = tiny_td3_recipe(tmp_path / "tiny.yaml")
    run = tmp_path / "run"
    assert (
        gcnt(["train", str(recipe), "device=cpu", f"run_dir={run}", f"td3.schedule={schedule}"])
        == 0
    )
    graphs = ["compile.cudagraphs=true", "compile.replay_on_device=true"]
    with Replays() as replays:
        resume = [
            "train",
            "--resume",
            str(run),
            "device=cuda",
            *graphs,
            "collector.total_frames=80",
        ]
        assert gcnt(resume) == 0, capsys.readouterr().err
    replays.check(True)
    assert _all_cpu(run / "checkpoints" / "last.pt")
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert rows[-1]["env_steps"] == 80
    assert gcnt(["eval", str(run), "--robots", "train", "--episodes", "1"]) == 0
