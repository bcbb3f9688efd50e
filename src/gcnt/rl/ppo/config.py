"""The ``ppo:`` recipe section (the paper's PPO settings on UNIMAL, table 4, are the defaults).

Imported by the recipe loader without torch, so keep this module free of heavy imports.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from gcnt.rl.config_check import check_range


@dataclass
class PPOConfig:
    # --- collection
    #: parallel environments stepping in lockstep (the paper: 32); with robot sampling each is a
    #: slot that takes a newly drawn training robot at every reset
    num_envs: int = 32
    #: lockstep steps per environment and iteration (the paper: 2560; 32 x 2560 = 81920 frames)
    steps_per_env: int = 2560
    #: "single": one process steps all envs (threads for the physics); "multi": torchrl's
    #: MultiSyncCollector over ``workers`` processes, each stepping num_envs / workers envs (or
    #: worker_envs)
    collector: Literal["single", "multi"] = "single"
    #: processes of the "multi" collector (must divide num_envs)
    workers: int = 2
    #: envs each "multi" worker steps (0: num_envs / workers). A step's fixed costs (the policy
    #: call, TorchRL's step, the featuriser) are per batched step, so a worker with few envs pays
    #: them for few frames: set it to num_envs (or >= 32) to keep the single process's batch per
    #: worker. An iteration still collects num_envs x steps_per_env frames, as workers x
    #: worker_envs envs of num_envs x steps_per_env / (workers x worker_envs) steps each (more,
    #: shorter trajectories; the run then repeats for its seed, workers and worker_envs)
    worker_envs: int = 0
    #: "sampled": a robot per episode, drawn against "the rich get richer" (uniform first, then
    #: p_i proportional to 1000 / EMA of robot i's episode length); "fixed": num_envs / robots
    #: copies of each robot (num_envs must be a multiple of the robot count)
    robot_sampling: Literal["sampled", "fixed"] = "sampled"
    #: iterations of uniform robot sampling before the episode-length weights take over
    uniform_iterations: int = 30
    #: episodes of a robot averaged before its EMA starts, and the EMA's weight of a new length
    ema_warmup_episodes: int = 10
    ema_alpha: float = 0.1
    # --- optimisation
    #: PPO epochs over each iteration's data and mini-batch size (the paper: 8 and 5120)
    epochs: int = 8
    minibatch_size: int = 5120
    gamma: float = 0.99
    gae_lambda: float = 0.95
    #: policy ratio clip, and the value clip around the old value (<= 0: no value clipping)
    clip_epsilon: float = 0.2
    clip_value: float = 0.2
    #: the critic's weight in the loss (the paper: 0.2), as the originals' ``VALUE_COEF``: the
    #: critic term is critic_coeff · ½ · mean(max((v - R)², (v_clip - R)²))
    critic_coeff: float = 0.2
    #: entropy bonus weight (the paper: 0)
    entropy_coeff: float = 0.0
    #: KL early stop: before each mini-batch step, if mean(log pi_old - log pi) of the mini-batch
    #: exceeds this, the rest of the iteration is skipped. A number, or a mapping from network
    #: name to threshold with a ``default`` entry (the paper's table 5 differs per method and
    #: world). <= 0: never stop
    kl_stop: float | dict[str, float] = field(default_factory=lambda: {"default": 0.05})
    #: dropout (in networks that have any) also on while collecting and while computing the
    #: iteration's values, as MetaMorph's code runs (its network never leaves training mode);
    #: off: dropout only in the update. A bool, or a mapping from network name to bool with a
    #: ``default`` entry
    collect_dropout: bool | dict[str, bool] = field(default_factory=lambda: {"default": False})
    #: Adam learning rate (peak), epsilon, and the schedule: linear warm-up from
    #: ``warmup_start`` x lr over ``warmup_iterations``, times a cosine decay over the run's
    #: iterations ("cosine") or a constant ("constant")
    lr: float = 3e-4
    adam_eps: float = 1e-5
    lr_schedule: Literal["cosine", "constant"] = "cosine"
    warmup_iterations: int = 5
    warmup_start: float = 0.1
    #: gradient-norm clip over actor and critic (<= 0: off)
    max_grad_norm: float = 0.5
    #: normalise advantages over the whole iteration (mean 0, std 1)
    normalize_advantage: bool = True
    # --- normalisation
    #: observations normalised per limb slot x feature with running mean / std, clipped
    obs_norm: bool = True
    obs_clip: float = 10.0
    #: rewards divided by the running std of the discounted return, clipped
    reward_scaling: bool = True
    reward_clip: float = 10.0
    # --- policy
    #: Gaussian std: "fixed" (not trained) at init_std, or "learned" (state-independent log-std)
    std: Literal["fixed", "learned"] = "fixed"
    init_std: float = 0.9

    def kl_threshold(self, network: str) -> float:
        """The KL early-stop threshold of method ``network`` (<= 0: off)."""
        if isinstance(self.kl_stop, dict):
            return float(self.kl_stop.get(network, self.kl_stop["default"]))
        return float(self.kl_stop)

    def dropout_while_collecting(self, network: str) -> bool:
        """Whether method ``network`` collects with its dropout on (``collect_dropout``)."""
        if isinstance(self.collect_dropout, dict):
            return bool(self.collect_dropout.get(network, self.collect_dropout["default"]))
        return bool(self.collect_dropout)

    def check_recipe(self, recipe) -> None:
        """The ``compile:`` switches PPO cannot honour: a ValueError naming the switch."""
        if recipe.compile.cudagraphs:
            raise ValueError(
                "compile.cudagraphs=true is for TD3: PPO decides between a mini-batch's forward "
                "pass and its optimiser step whether to stop early on KL (ppo.kl_stop), which a "
                "captured graph cannot; use compile.compile=true (the loss forward compiled)"
            )

    def check(self) -> None:
        """Values that cannot train: a ValueError naming the key."""
        check_range(
            self,
            ">= 1",
            "num_envs",
            "steps_per_env",
            "workers",
            "epochs",
            "minibatch_size",
            "ema_warmup_episodes",
        )
        check_range(self, ">= 0", "uniform_iterations", "warmup_iterations", "worker_envs")
        if self.collector == "multi" and self.worker_envs:
            envs = self.workers * self.worker_envs
            if (self.num_envs * self.steps_per_env) % envs:
                raise ValueError(
                    f"worker_envs: num_envs x steps_per_env ({self.num_envs * self.steps_per_env})"
                    f" must be a multiple of workers x worker_envs ({envs})"
                )
        check_range(
            self, "positive finite", "lr", "adam_eps", "init_std", "obs_clip", "reward_clip"
        )
        check_range(self, "[0, 1]", "gamma", "gae_lambda", "ema_alpha", "warmup_start")
        check_range(
            self, ">= 0 finite", "clip_epsilon", "clip_value", "critic_coeff", "entropy_coeff"
        )
        if self.clip_epsilon <= 0:
            raise ValueError(f"clip_epsilon must be > 0, got {self.clip_epsilon}")
        if isinstance(self.kl_stop, dict):
            if "default" not in self.kl_stop:
                raise ValueError(
                    f"kl_stop: a mapping needs a 'default' entry, got keys {sorted(self.kl_stop)}"
                )
            for name, v in self.kl_stop.items():
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    raise ValueError(f"kl_stop.{name}: expected a number, got {v!r}")
        if isinstance(self.collect_dropout, dict):
            if "default" not in self.collect_dropout:
                raise ValueError(
                    "collect_dropout: a mapping needs a 'default' entry, got keys "
                    f"{sorted(self.collect_dropout)}"
                )
            bad = {k: v for k, v in self.collect_dropout.items() if not isinstance(v, bool)}
        else:
            bad = {} if isinstance(self.collect_dropout, bool) else {"": self.collect_dropout}
        for name, v in bad.items():
            key = f"collect_dropout.{name}" if name else "collect_dropout"
            raise ValueError(f"{key}: expected true or false, got {v!r}")
        if self.collector == "multi" and self.num_envs % self.workers:
            raise ValueError(
                f"collector 'multi': workers ({self.workers}) must divide num_envs "
                f"({self.num_envs})"
            )
        frames = self.num_envs * self.steps_per_env
        if self.minibatch_size > frames:
            raise ValueError(
                f"minibatch_size ({self.minibatch_size}) exceeds the frames per iteration "
                f"(num_envs x steps_per_env = {frames})"
            )
