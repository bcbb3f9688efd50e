"""Where a run's tensors live, and the one boundary they cross.

MuJoCo and the env run on the CPU: observations, rewards and done flags are born there, and
actions go back there. The networks, the robot tables their chains read, the losses, the
optimisers' state, PPO's rollout batch and observation statistics, and (with
``compile.replay_on_device``) TD3's replay live on ``recipe.device``. Batches cross once:

* collection: torchrl's collector casts each step's input to ``policy_device`` and the action
  back to ``env_device`` (``gcnt.rl.loop.make_collector``);
* evaluation, videos and benchmark rollouts, which call a policy outside a collector, wrap it in
  :class:`OnDevice`;
* learning: a collected batch is moved to the device when an update starts (TD3's
  ``TD3Learner.step``, PPO's ``PPOLearner.learn``).

Checkpoints hold CPU tensors only (:func:`gcnt.run.directory.plain_state`) and are loaded onto the
CPU; each ``load_state_dict`` places what it restores (modules copy into their parameters,
optimisers through :func:`load_optimizer_state`), so a run trained on a GPU evaluates or resumes
on a CPU and back, with its optimiser state.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase


class OnDevice(TensorDictModuleBase):
    """``policy`` run on ``device`` for inputs that live elsewhere: the keys it reads are moved
    to ``device``, the keys it writes come back on the input's device. Inputs already on
    ``device`` pass through untouched."""

    def __init__(self, policy: TensorDictModuleBase, device: str | torch.device) -> None:
        super().__init__()
        self.policy = policy
        self.device = torch.device(device)
        self.in_keys = list(policy.in_keys)
        self.out_keys = list(policy.out_keys)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        home = tensordict.device
        if home == self.device:
            return self.policy(tensordict)
        sub = tensordict.select(*self.in_keys, strict=False).to(self.device)
        out = self.policy(sub)
        for key in self.out_keys:
            value = out.get(key, None)
            if value is not None:
                tensordict.set(key, value.to(home) if home is not None else value.cpu())
        return tensordict


#: optimiser options that follow the device and the speed switches of the run that built the
#: optimiser, not the run that saved its state
RUN_FLAGS = ("capturable", "fused", "foreach", "differentiable")


def load_optimizer_state(opt: torch.optim.Optimizer, state: dict) -> None:
    """``opt.load_state_dict(state)`` for a run that may have changed device or switches.

    torch restores the saved param groups' flags with the state, so a run trained on a CPU
    (``fused``) and resumed with CUDA graphs would keep ``capturable=False`` and fail at capture,
    and a graphed run resumed on a CPU would keep ``capturable=True`` with CPU step counters.
    The flags stay as this run built them, and each step counter goes where they want it: on the
    parameter's device for a capturable or fused optimiser, on the CPU otherwise (a host scalar,
    so that a non-capturable step never synchronises with the device)."""
    own = [{k: group[k] for k in RUN_FLAGS if k in group} for group in opt.param_groups]
    opt.load_state_dict(state)
    for group, flags in zip(opt.param_groups, own, strict=True):
        group.update(flags)
        on_param = bool(group.get("capturable") or group.get("fused"))
        for p in group["params"]:
            step = opt.state.get(p, {}).get("step")
            if isinstance(step, torch.Tensor):
                opt.state[p]["step"] = step.to(p.device if on_param else torch.device("cpu"))


def on_device(policy: TensorDictModuleBase, device: str | torch.device) -> TensorDictModuleBase:
    """``policy`` itself on a CPU run, else wrapped in :class:`OnDevice`."""
    if torch.device(device).type == "cpu":
        return policy
    return OnDevice(policy, device)
