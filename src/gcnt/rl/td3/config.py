"""The ``td3:`` recipe section (the paper's TD3 settings on SMPENV are the defaults).

Imported by the recipe loader without torch, so keep this module free of heavy imports.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Literal

from gcnt.rl.config_check import check_range


@dataclass
class TD3Config:
    # --- collection
    #: first steps with uniform random actions in [-1, 1], per training robot or over all of
    #: them (``random_counted``); rounded up to whole collector batches
    init_random_frames: int = 10_000
    #: "per_robot": the random phase lasts ``init_random_frames`` times the number of training
    #: robots (SWAT's and AMORPHEUS's main.py: ``start_timesteps * num_envs_train``), "total":
    #: ``init_random_frames`` over all robots (SMP's main.py)
    random_counted: Literal["per_robot", "total"] = "per_robot"
    #: update from the first collection round on, on the random phase's data too (the original
    #: main.py files train after every round); false: the first update follows the random phase
    update_during_random: bool = True
    #: "paper": lockstep until every robot has finished an episode, then per-robot updates from
    #: its own buffer, as many as its transitions. "mixed": every ``steps_per_batch`` lockstep
    #: steps, updates on padded batches that mix all robots (batch_size samples of each robot)
    schedule: Literal["paper", "mixed"] = "paper"
    #: lockstep steps per collector batch (in both schedules; "paper" checks for finished
    #: robots at these boundaries)
    steps_per_batch: int = 50
    #: which steps of a "paper" round are counted and stored. "store_all_count_first": each
    #: sub-env's steps until its first episode of the round ends are counted; a sub-env that
    #: finished goes on stepping (new episodes) while the others finish, and those steps are
    #: stored but not counted; every sub-env starts the next round with a new episode (the
    #: SWAT/AMORPHEUS main.py over baselines' SubprocVecEnv, whose worker resets a finished env
    #: itself). "first_episode": as that, but the steps after the first episode are dropped.
    #: "all": every step of the round counted and stored
    round_steps: Literal["store_all_count_first", "first_episode", "all"] = "store_all_count_first"
    #: how a "paper" round's updates are shared out among the robots. "mean": every robot gets
    #: the mean of the robots' counted steps of the round (the originals' ``TD3.train``:
    #: ``per_morph_iter = sum(iterations_list) // len(envs_train_names)``); "own": each robot
    #: its own counted steps (robots that fall early get fewer updates)
    round_updates: Literal["mean", "own"] = "mean"
    #: a mini-batch of one robot (the "paper" schedule) at that robot's own limb count, not
    #: padded to the largest robot's: the same losses and gradients (tested in float64) at fewer
    #: FLOPs, for methods whose outputs do not depend on padding (``padding_free`` in the network
    #: registry); false: every batch padded (to compare speeds)
    trim_padding: bool = True
    #: every this many counted env steps (0: never), measure the learner on a fixed probe of
    #: random-action transitions (``gcnt.rl.td3.probe``): ``probe/q1_mean``,
    #: ``probe/saturated`` and ``probe/action_std`` in the next metrics row
    probe_interval: int = 0
    #: the probe's lockstep steps of uniform-random actions (transitions: this x robots)
    probe_steps: int = 250
    #: std of the Gaussian exploration noise added to the actor's actions
    exploration_noise: float = 0.126
    # --- replay
    #: transitions kept per robot (the paper: 500k) ...
    buffer_size_per_robot: int = 500_000
    #: ... and over all robots (the paper: 4M): each robot gets min(per robot, total / robots)
    buffer_total_size: int = 4_000_000
    #: mini-batch size (per robot, also in the mixed schedule)
    batch_size: int = 100
    #: also checkpoint the replay (large; makes resume exact): checkpoints/buffers/replay-<N>.pt,
    #: written atomically next to the checkpoint that names it
    checkpoint_buffers: bool = False
    # --- optimisation
    #: Adam learning rate of actor and critic
    lr: float = 1e-4
    gamma: float = 0.99
    #: soft target update rate (target = (1 - tau) target + tau online)
    tau: float = 0.046
    #: critic updates per actor (and target) update
    policy_delay: int = 2
    #: target-policy smoothing noise std and clip
    policy_noise: float = 0.2
    noise_clip: float = 0.5
    #: gradient-norm clip of actor and critic (<= 0: off)
    max_grad_norm: float = 0.1
    #: critic updates per stored environment step (the paper: 1)
    updates_per_step: float = 1.0
    #: TD target and critic loss of the per-limb critics (``gcnt.rl.td3.loss.TARGET_RULES``):
    #: "limb" (each limb its own target, the AMORPHEUS/SWAT/SMP code), "robot_mean" (one target
    #: per robot from the mean over real limbs), "robot_sum" (one per robot from the summed limb
    #: Qs); "auto": "robot_sum" for the monolithic MLP (sr, mlp: plain single-robot TD3), "limb"
    #: for every other method
    target: Literal["auto", "limb", "robot_mean", "robot_sum"] = "auto"

    def check(self) -> None:
        """Values that cannot train: a ValueError naming the key."""
        check_range(
            self,
            ">= 1",
            "steps_per_batch",
            "batch_size",
            "buffer_size_per_robot",
            "buffer_total_size",
            "policy_delay",
        )
        check_range(self, ">= 0", "init_random_frames", "probe_interval")
        check_range(self, ">= 1", "probe_steps")
        check_range(self, "positive finite", "lr", "tau", "updates_per_step")
        check_range(self, "[0, 1]", "gamma")
        if not self.tau <= 1.0:
            raise ValueError(f"tau must be in (0, 1], got {self.tau}")
        check_range(self, ">= 0 finite", "exploration_noise", "policy_noise", "noise_clip")
        if self.max_grad_norm != self.max_grad_norm or self.max_grad_norm == float("inf"):
            raise ValueError(f"max_grad_norm must be finite (<= 0: off), got {self.max_grad_norm}")
        rounds = ("store_all_count_first", "first_episode", "all")
        if self.round_steps not in rounds:
            raise ValueError(
                f"round_steps must be one of {', '.join(rounds)}, got {self.round_steps!r}"
            )
        if self.round_updates not in ("mean", "own"):
            raise ValueError(f"round_updates must be mean or own, got {self.round_updates!r}")
        if self.random_counted not in ("per_robot", "total"):
            raise ValueError(
                f"random_counted must be per_robot or total, got {self.random_counted!r}"
            )
        if self.target not in ("auto", "limb", "robot_mean", "robot_sum"):
            raise ValueError(
                f"target must be one of auto, limb, robot_mean, robot_sum, got {self.target!r}"
            )
        if self.batch_size > min(self.buffer_size_per_robot, self.buffer_total_size):
            raise ValueError(
                f"batch_size {self.batch_size} is larger than the replay buffer "
                f"(buffer_size_per_robot {self.buffer_size_per_robot}, buffer_total_size "
                f"{self.buffer_total_size})"
            )

    def check_recipe(self, recipe) -> None:
        """Relations with the shared settings (``recipe`` is the whole recipe)."""
        self.check_random_phase(recipe.collector.total_frames, 1)

    def check_random_phase(self, total_frames: int, num_robots: int) -> None:
        """A random phase as long as the run is refused: the policy would never act."""
        random = self.random_frames(num_robots)
        if random >= total_frames:
            per = (
                f" x {num_robots} robots (td3.random_counted=per_robot)"
                if random != (self.init_random_frames)
                else ""
            )
            raise ValueError(
                f"td3.init_random_frames ({self.init_random_frames}{per}) must be below "
                f"collector.total_frames ({total_frames}): the policy would never act"
            )

    def random_frames(self, num_robots: int) -> int:
        """The env steps of uniform-random actions over all ``num_robots`` training robots
        (before rounding to whole collector batches)."""
        per_robot = self.random_counted == "per_robot"
        return self.init_random_frames * (max(1, num_robots) if per_robot else 1)

    def planned_updates(self, total_frames: int, num_robots: int) -> float:
        """About how many updates a run of ``total_frames`` env steps on ``num_robots`` robots
        makes: ``updates_per_step`` per stored step after the random phase (from the first step
        with ``update_during_random``), one mixed update per step of every robot."""
        frames = total_frames - (0 if self.update_during_random else self.random_frames(num_robots))
        per_step = self.updates_per_step / (max(1, num_robots) if self.schedule == "mixed" else 1)
        return max(0, frames) * per_step

    #: what a recorded run whose td3 section lacks a key trained with (the key came later)
    BEFORE_KEY: ClassVar[dict[str, Any]] = {
        "random_counted": "total",
        "update_during_random": False,
        "round_steps": "all",
        "round_updates": "own",
    }


#: networks whose outputs are a monolithic MLP's per-slot outputs rather than a per-limb module's
MONOLITHIC = ("sr", "mlp")


def target_rule(config: TD3Config, network: str) -> str:
    """The TD target rule a run uses: ``config.target``, or for "auto" the network's original."""
    if config.target != "auto":
        return config.target
    return "robot_sum" if network in MONOLITHIC else "limb"
