"""``gcnt params``: parameter counts of every method, actor and critic, like the paper's tables 7-8.

gcnt params                    SMPENV sizes (TD3 actor / critic, F=19, A=1, the CWHH++ robots)
gcnt params --preset unimal    UNIMAL sizes (PPO actor / critic, F=52, A=2, random trees ≤ 12)

Counts depend on the robots only through K (the MLP baseline's input size) and the WL vector
width. Parameters of the robot table are buffers and are not counted.

Against the paper (which does not say what it counts):
* UNIMAL (table 8) matches actor + critic: MetaMorph* 3,315,075 vs 3,313,183 here for the plain
  Transformer at the same sizes (-0.06%); GCNT 3,333,583 vs 3,345,185 here, the gap being mostly
  the WL vector (64 buckets here; the paper's difference suggests about 16).
* SMPENV (table 7) is about half of one AMORPHEUS actor (202,389 vs 400,404). Its method deltas
  look like partial counts: SWAT - AMORPHEUS = 8 = Linear(3 -> 2 heads), the relational bias,
  without the traversal tables; GCNT - AMORPHEUS = 4,224 = Linear(16 + 16 -> 128), the [GCN ‖ WL]
  projection, without the GCN layers or the distance tables. SMP's 694,410 implies much wider
  MLPs than the message 32 / hidden 64 used here.
"""

from __future__ import annotations

import argparse

from gcnt.envs.robot_table import robot_table
from gcnt.nn import count_parameters, make_network
from gcnt.nn.synthetic import random_robots, smpenv_like_robots

METHODS = ("smp", "amorpheus", "swat", "gcnt", "gcnt_no_gcn", "gcnt_no_wl", "gcnt_no_dist", "mlp")

#: paper appendix tables 7 (SMPENV) and 8 (UNIMAL, flat terrain); MetaMorph* is the paper's
#: closest UNIMAL analogue of the plain Transformer (pre-LN there, post-LN here)
PAPER = {
    "smpenv": {"smp": 694_410, "amorpheus": 202_389, "swat": 202_397, "gcnt": 206_613},
    "unimal": {"amorpheus": 3_315_075, "gcnt": 3_333_583},
}

SETUPS = {
    # preset: (obs_dim, num_actions, actor role, critic role)
    "smpenv": (19, 1, "td3_actor", "td3_critic"),
    "unimal": (52, 2, "ppo_actor", "ppo_critic"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--preset",
        choices=sorted(SETUPS),
        default="smpenv",
        help="network sizes and observation/action widths (default: smpenv)",
    )


def count_table(preset: str) -> list[dict]:
    obs_dim, num_actions, actor_role, critic_role = SETUPS[preset]
    if preset == "smpenv":
        robots = smpenv_like_robots()
    else:
        robots = random_robots([12, 7, 9, 10], seed=0)
    table = robot_table(robots, None, num_actions)
    rows = []
    for name in METHODS:
        kw = dict(table=table, obs_dim=obs_dim, num_actions=num_actions, preset=preset)
        actor = count_parameters(make_network(name, actor_role, **kw))
        critic = count_parameters(make_network(name, critic_role, **kw))
        rows.append(
            {"method": name, "actor": actor, "critic": critic, "paper": PAPER[preset].get(name)}
        )
    return rows


def run(args: argparse.Namespace) -> int:
    obs_dim, num_actions, actor_role, critic_role = SETUPS[args.preset]
    rows = count_table(args.preset)
    base = next(r for r in rows if r["method"] == "amorpheus")
    twin = " (one of TD3's twin critics)" if critic_role == "td3_critic" else ""
    print(
        f"preset {args.preset}: F={obs_dim}, A={num_actions}; actor = {actor_role}, "
        f"critic = {critic_role}{twin}"
    )
    head = (
        f"{'method':<14}{'actor':>12}{'critic':>12}{'actor+critic':>14}"
        f"{'vs AMORPHEUS':>14}{'paper':>12}"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        rel = f"{r['actor'] / base['actor'] - 1:+.1%}"
        paper = f"{r['paper']:,}" if r["paper"] else "-"
        both = r["actor"] + r["critic"]
        print(
            f"{r['method']:<14}{r['actor']:>12,}{r['critic']:>12,}{both:>14,}{rel:>14}{paper:>12}"
        )
    print(
        "vs AMORPHEUS: actor size relative to the AMORPHEUS actor. paper: appendix table "
        f"{7 if args.preset == 'smpenv' else 8}"
        + ("" if args.preset == "smpenv" else " (flat terrain; 'amorpheus' row: MetaMorph*)")
        + "; the paper does not state what it "
        "counts."
    )
    return 0
