"""A run moves between devices and switches with its state, on any machine: the checkpoint is read
on the CPU and placed by each ``load_state_dict``; an optimiser keeps the flags of the run that
built it, not of the run that saved it; a run recorded with CUDA-only switches goes on without
them where it has no CUDA, saying so in one line; the exploration policy reads nothing on the
host (a CUDA graph of the collector's policy cannot)."""

from __future__ import annotations

import pytest
import torch
import yaml
from cli_helpers import error_line, tiny_td3_recipe
from tensordict import TensorDict
from torch.utils._python_dispatch import TorchDispatchMode
from torchrl.data import Bounded
from torchrl.modules import AdditiveGaussianModule

from gcnt.cli import main as gcnt
from gcnt.keys import ACTION
from gcnt.rl.device import load_optimizer_state
from gcnt.rl.td3.exploration import GaussianExploration
from gcnt.run.record import load_run_recipe


def _adam_state(**flags) -> dict:
    torch.manual_seed(0)
    p = torch.nn.Parameter(torch.randn(4, 3, dtype=torch.float64))
    opt = torch.optim.Adam([p], lr=1e-3, **flags)
    for _ in range(3):
        (p**2).sum().backward()
        opt.step()
        opt.zero_grad()
    return opt.state_dict()


def test_an_optimiser_state_saved_by_a_graphed_run_steps_on_a_cpu():
    saved = _adam_state()
    saved["param_groups"][0].update(capturable=True, fused=None)  # as a CUDA-graphed run saves it
    p = torch.nn.Parameter(torch.zeros(4, 3, dtype=torch.float64))
    opt = torch.optim.Adam([p], lr=1e-3, fused=True)
    load_optimizer_state(opt, saved)
    assert opt.param_groups[0]["capturable"] is False and opt.param_groups[0]["fused"] is True
    assert float(opt.state[p]["step"]) == 3.0
    (p**2).sum().backward()
    opt.step()  # torch.optim's own load_state_dict leaves capturable=True: this step raises
    assert float(opt.state[p]["step"]) == 4.0


def test_an_optimiser_state_saved_on_a_cpu_keeps_this_runs_capturable_flag():
    saved = _adam_state(fused=True)
    p = torch.nn.Parameter(torch.zeros(4, 3, dtype=torch.float64))
    opt = torch.optim.Adam([p], lr=1e-3, capturable=True)
    load_optimizer_state(opt, saved)
    group = opt.param_groups[0]
    assert group["capturable"] is True and not group["fused"]
    step = opt.state[p]["step"]
    assert step.device == p.device and float(step) == 3.0
    # the moments are the saved ones
    assert torch.equal(opt.state[p]["exp_avg"], saved["state"][0]["exp_avg"])


def _graphed_checkpoint(run) -> None:
    """Rewrite ``run``'s checkpoint as a CUDA-graphed run writes it: capturable optimisers."""
    path = run / "checkpoints" / "last.pt"
    state = torch.load(path, weights_only=True)
    for key in ("actor_opt", "critic_opt"):
        for group in state["learner"][key]["param_groups"]:
            group.update(capturable=True, fused=None)
    torch.save(state, path)


def test_a_run_trained_with_cuda_graphs_resumes_on_a_cpu_with_its_optimiser(tmp_path, capsys):
    recipe = tiny_td3_recipe(tmp_path / "tiny.yaml", test_robots=())
    run = tmp_path / "run"
    assert gcnt(["train", str(recipe), f"run_dir={run}", "logger.log_interval=5"]) == 0
    _graphed_checkpoint(run)
    # the recorded recipe as the GPU run wrote it
    recorded = yaml.safe_load((run / "recipe.yaml").read_text())
    recorded["device"] = "cuda"
    recorded.setdefault("compile", {}).update(cudagraphs=True, replay_on_device=True)
    (run / "recipe.yaml").write_text(yaml.safe_dump(recorded))
    capsys.readouterr()
    resume = ["train", "--resume", str(run), "device=cpu", "collector.total_frames=60"]
    assert gcnt(resume) == 0
    said = [line for line in capsys.readouterr().err.splitlines() if "CUDA only" in line]
    assert len(said) == 1 and "compile.cudagraphs, compile.replay_on_device" in said[0], said
    rows = [yaml.safe_load(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert rows[-1]["env_steps"] == 60 and rows[-1]["updates"] > rows[0]["updates"]
    again = yaml.safe_load((run / "recipe.yaml").read_text())
    assert again["device"] == "cpu" and again["compile"]["cudagraphs"] is False


def _recorded_on_cuda(tmp_path):
    recipe = tiny_td3_recipe(tmp_path / "tiny.yaml")
    data = yaml.safe_load(recipe.read_text())
    data.update(device="cuda", compile={"cudagraphs": True, "amp": True})
    path = tmp_path / "recipe.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.skipif(torch.cuda.is_available(), reason="reads a GPU run where CUDA is missing")
def test_a_gpu_runs_recipe_is_read_on_the_cpu_without_its_cuda_switches(tmp_path):
    path = _recorded_on_cuda(tmp_path)
    recipe = load_run_recipe(path, anywhere=True)
    assert recipe.device == "cpu" and not recipe.compile.cudagraphs and not recipe.compile.amp
    with pytest.raises(ValueError, match="no CUDA GPU is available here; use device=cpu"):
        load_run_recipe(path)  # a resume says which override moves it
    moved = load_run_recipe(path, ["device=cpu"])
    assert moved.device == "cpu" and not moved.compile.cudagraphs
    with pytest.raises(ValueError, match="compile.cudagraphs=true needs a CUDA device"):
        load_run_recipe(path, ["device=cpu", "compile.cudagraphs=true"])  # asked for: refused


def test_resuming_with_a_cuda_switch_asked_for_on_a_cpu_is_one_line(trained, capsys):
    line = error_line(
        capsys, ["train", "--resume", str(trained), "device=cpu", "compile.cudagraphs=true"]
    )
    assert "compile.cudagraphs=true needs a CUDA device" in line


class _HostReads(TorchDispatchMode):
    """Counts the aten ops that read a tensor's value on the host."""

    READS = {"aten::_local_scalar_dense", "aten::is_nonzero", "aten::item"}

    def __init__(self):
        super().__init__()
        self.reads = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.reads += func._schema.name in self.READS
        return func(*args, **(kwargs or {}))


def _spec():
    # float32 as the envs' actions (torchrl draws its noise in the default dtype)
    low = -torch.linspace(0.5, 1.0, 5).unsqueeze(-1)
    return Bounded(low, -low, shape=(5, 1))


def test_exploration_noise_is_torchrls_without_reading_on_the_host():
    ours = GaussianExploration(_spec(), 0.3)
    theirs = AdditiveGaussianModule(
        _spec(), sigma_init=0.3, sigma_end=0.3, annealing_num_steps=1, action_key=ACTION
    )
    x = torch.rand(64, 5, 1) * 2 - 1
    torch.manual_seed(1)
    with _HostReads() as mode:
        a = ours(TensorDict({ACTION: x.clone()}, [64]))[ACTION]
    assert mode.reads == 0
    torch.manual_seed(1)
    b = theirs(TensorDict({ACTION: x.clone()}, [64]))[ACTION]
    assert torch.allclose(a, b, rtol=0, atol=1e-6)
    assert bool((a >= _spec().space.low).all() and (a <= _spec().space.high).all())
    assert not torch.allclose(a, x)  # noise was added


@pytest.mark.skipif(torch.cuda.is_available(), reason="reads a GPU run where CUDA is missing")
def test_a_gpu_run_evaluates_on_a_machine_without_cuda(trained, tmp_path):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(trained, run)
    _graphed_checkpoint(run)
    recorded = yaml.safe_load((run / "recipe.yaml").read_text())
    recorded["device"] = "cuda"
    recorded.setdefault("compile", {}).update(cudagraphs=True, amp=True)
    (run / "recipe.yaml").write_text(yaml.safe_dump(recorded))
    out = tmp_path / "eval.json"
    assert gcnt(["eval", str(run), "--robots", "train", "--episodes", "1", "--json", str(out)]) == 0
    assert yaml.safe_load(out.read_text())["robots"]
