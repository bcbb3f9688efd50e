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

Checkpoints hold CPU tensors only (:func:`gcnt.rl.run_dir.plain_state`) and are loaded with
``map_location`` onto the resuming run's device, so a run trained on a GPU evaluates or resumes
on a CPU and back.
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


def on_device(policy: TensorDictModuleBase, device: str | torch.device) -> TensorDictModuleBase:
    """``policy`` itself on a CPU run, else wrapped in :class:`OnDevice`."""
    if torch.device(device).type == "cpu":
        return policy
    return OnDevice(policy, device)
