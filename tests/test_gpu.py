"""On a CUDA device (``pytest -m gpu``; skipped, saying why, where there is none): every TD3
method in both schedules and every accelerator switch, and every PPO method on UNIMAL, trains,
checkpoints (CPU tensors), resumes and evaluates with ``device=cuda``, or is refused in one line
before anything runs. Tiny sizes: what is checked is placement, not learning."""

from __future__ import annotations

import json

import pytest
import torch
import yaml
from cli_helpers import tiny_td3_recipe

from gcnt.cli import main as gcnt

pytestmark = [pytest.mark.gpu]

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
}


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


def _train_resume_eval(capsys, tmp_path, recipe, overrides: list[str], frames=(80, 120)) -> None:
    """train -> checkpoint (CPU tensors) -> resume to ``frames[0]`` steps -> eval, all on cuda,
    then resume on the CPU to ``frames[1]``; or one error line (exit 2) before any run
    directory exists."""
    run = tmp_path / "run"
    argv = ["train", str(recipe), "device=cuda", f"run_dir={run}", *overrides]
    capsys.readouterr()
    code = gcnt(argv)
    err = capsys.readouterr().err
    if code == 2:  # refused: one line, nothing run
        lines = [line for line in err.splitlines() if line.startswith("gcnt ")]
        assert len(lines) == 1 and "Traceback" not in err, err
        assert not (run / "checkpoints").exists()
        return
    assert code == 0, err
    ckpt = run / "checkpoints" / "last.pt"
    assert _all_cpu(ckpt)
    assert gcnt(["train", "--resume", str(run), f"collector.total_frames={frames[0]}"]) == 0
    assert _all_cpu(ckpt)
    out = tmp_path / "eval.json"
    assert gcnt(["eval", str(run), "--robots", "train", "--episodes", "1", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["robots"]
    # a run trained on the GPU resumes on the CPU
    cpu = ["train", "--resume", str(run), "device=cpu", f"collector.total_frames={frames[1]}"]
    assert gcnt(cpu) == 0


@pytest.mark.parametrize("schedule", ["paper", "mixed"])
@pytest.mark.parametrize("method", TD3_METHODS)
def test_td3_method_on_cuda(capsys, tmp_path, method, schedule):
    recipe = tiny_td3_recipe(tmp_path / "tiny.yaml")
    sizes = SMALL.get(method)
    over = [f"network.name={method}", f"td3.schedule={schedule}"]
    if sizes is not None:
        over.append(f"network.kwargs={json.dumps(sizes)}")
    _train_resume_eval(capsys, tmp_path, recipe, over)


@pytest.mark.parametrize("schedule", ["paper", "mixed"])
@pytest.mark.parametrize("switch", list(SWITCHES))
@pytest.mark.parametrize("method", ["gcnt", "smp"])
def test_td3_switches_on_cuda(capsys, tmp_path, method, switch, schedule):
    recipe = tiny_td3_recipe(tmp_path / "tiny.yaml")
    over = [f"network.name={method}", f"td3.schedule={schedule}", *SWITCHES[switch]]
    if method in SMALL:
        over.append(f"network.kwargs={json.dumps(SMALL[method])}")
    _train_resume_eval(capsys, tmp_path, recipe, over)


@pytest.mark.parametrize(
    "method", ["metamorph", "metamorph_star", "modumorph", "gcnt", "gcnt_hn", "sr"]
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


@pytest.mark.parametrize("switch", list(SWITCHES))
def test_stacked_seeds_on_cuda(capsys, tmp_path, switch):
    """``gcnt train --seeds 0,1`` (one vmapped update for both seeds) on cuda under each switch:
    both runs finish with CPU checkpoints and evaluate, or one error line before any run."""
    recipe = tiny_td3_recipe(tmp_path / "tiny.yaml")
    base = tmp_path / "seeds"
    argv = ["train", str(recipe), "--seeds", "0,1", "device=cuda", f"run_dir={base}"]
    code = gcnt([*argv, "td3.schedule=mixed", *SWITCHES[switch]])
    err = capsys.readouterr().err
    if code == 2:
        assert len([x for x in err.splitlines() if x.startswith("gcnt ")]) == 1, err
        assert not base.exists()
        return
    assert code == 0, err
    for seed in (0, 1):
        run = base / f"seed{seed}"
        assert _all_cpu(run / "checkpoints" / "last.pt")
        assert gcnt(["eval", str(run), "--robots", "train", "--episodes", "1"]) == 0
