"""Device placement on a machine without a GPU: the divergence check over tensors of several
devices, the one boundary a policy's inputs cross outside a collector (OnDevice), robot ids
following the robot table's device, and checkpoints that hold CPU tensors only. The same paths
on a real GPU are tests/test_gpu.py (``pytest -m gpu``)."""

from __future__ import annotations

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch.utils._pytree import tree_leaves

from gcnt.rl.device import OnDevice, on_device
from gcnt.rl.loop import _all_finite
from gcnt.rl.td3.tensor_chain import RobotBatch
from gcnt.run.directory import RunDir, plain_state


def test_divergence_check_groups_tensors_by_device():
    meta = torch.empty(4, 3, device="meta")
    state = {"net": {"w": torch.ones(3), "m": meta}, "opt": [torch.zeros(2, dtype=torch.float64)]}
    assert _all_finite(state)  # CPU float32, CPU float64 and meta in one state
    state["opt"].append(torch.tensor([1.0, float("nan")]))
    assert not _all_finite(state)
    state["opt"][-1] = torch.tensor([3e38, 3e38])  # the norm overflows, every element is finite
    assert _all_finite(state)


def test_on_device_moves_what_the_policy_reads_and_returns_what_it_writes():
    seen = []

    def act(obs):
        seen.append(obs.device)
        return obs * 2

    policy = TensorDictModule(act, ["obs"], ["action"])
    assert on_device(policy, "cpu") is policy  # nothing to cross on a CPU run
    wrapped = OnDevice(policy, "cpu")
    td = TensorDict({"obs": torch.ones(3, 2), "other": torch.zeros(3)}, [3])  # no device
    out = wrapped(td)
    assert out is td and torch.equal(td["action"], torch.full((3, 2), 2.0))
    assert seen == [torch.device("cpu")] and td["action"].device.type == "cpu"
    on_cpu = TensorDict({"obs": torch.ones(1, 2)}, [1], device="cpu")
    assert wrapped(on_cpu) is on_cpu  # already there: the policy's own call


def test_robot_ids_follow_the_robot_table_to_its_device():
    table = {("limbs", "mask"): torch.empty(5, 7, dtype=torch.bool, device="meta")}
    robots = RobotBatch(table, torch.tensor([0, 4, 4]))
    assert robots.ids.device.type == "meta"
    assert robots.gathered(("limbs", "mask")).shape == (3, 7)
    same = torch.tensor([1, 2])
    assert RobotBatch({("k",): torch.zeros(3, 1)}, same).ids is same


def test_checkpoint_tensors_are_detached_cpu_tensors(trained):
    w = torch.nn.Parameter(torch.ones(2))
    out = plain_state({"w": w})["w"]
    assert not out.requires_grad and out.data_ptr() == w.data_ptr()  # no copy on a CPU run
    # read as written (no map_location): where a tensor was saved is where it loads
    state = torch.load(RunDir(trained).checkpoint_path, weights_only=True)
    tensors = [x for x in tree_leaves(state) if isinstance(x, torch.Tensor)]
    assert tensors and all(t.device.type == "cpu" and not t.requires_grad for t in tensors)
