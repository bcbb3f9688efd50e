"""Parameter counts of every method, actor and critic, next to the paper's appendix tables 7
(SMPENV) and 8 (UNIMAL); ``gcnt params`` prints them, ``gcnt tables`` writes them.

``gcnt params``                    SMPENV: TD3 actor / critic at the SMPENV preset
``gcnt params --benchmark unimal`` UNIMAL: PPO actor / critic at the UNIMAL preset, per world
                                   (FT / Incline without a height map, MT / Obstacles with one)

Observation and action widths, worlds and the height-map width come from the benchmark record
(``gcnt.envs.benchmark.get_benchmark``); while no UNIMAL record is registered, the UNIMAL
contract's numbers are used (F = 52, A = 2, height map 1410 on MT and Obstacles). Counts depend on
the robots only through the padding K (SR's input, 12 on UNIMAL) and the WL width. The robot table
is buffers, never counted. The paper does not say what it counts; what it does count, as far as
the numbers reveal it:

* MetaMorph / MetaMorph*: actor + critic. Ours at 52 inputs are exactly 2,560 below the paper on
  every world = 2 networks × 10 inputs × 128: the paper's numbers match 62 inputs.
* ModuMorph: actor + critic of its public code, which also builds a plain limb embedding
  Linear(52→128) and a plain decoder it never uses (2 × 6,784 + 258 + 129 = 13,955 on FT/Incline,
  38,467 with MT's decoder, 46,787 with Obstacles'); ours omits them.
* GCNT: its overhead over MetaMorph* here is mostly the WL vector (64 buckets into
  Linear(23 + W → 128)); the paper's difference suggests a much smaller W.
* MT vs Obstacles: the decoder has one hidden layer of 64 on MT and two on Obstacles in both
  originals (``DECODER_DIMS``: ``configs/csr.yaml`` [64], ``configs/obstacle.yaml`` [64, 64]),
  none on FT and Incline; the second layer is 64 × 64 + 64 = 4,160 per network, the paper's
  +8,320 of every plain-decoder method from MT to Obstacles.
* SMPENV (table 7) is about half of one AMORPHEUS actor (202,389 vs 400,404 here) and its method
  deltas look like partial counts (SWAT − AMORPHEUS = 8 = the relational bias Linear(3→2) only).
* SMP (table 7: 694,410) is twice an actor: the original code (``huangwl18/modular-rl``) registers
  each module under two names for torchfold, so its ``state_dict`` lists every tensor twice, and
  2 × 347,205 (its both-way actor with 4 child slots, as on any set with humanoids, and a 20-wide
  limb input) is exactly the paper's number. The original's actor has 323,781 parameters with 2
  child slots (Walker++) and 347,141 with 4, at the real 19-wide input; gcnt's sums the children's
  messages (one slot) and has 312,101 (:data:`SMP_ORIGINAL_ACTOR`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import torch

from gcnt import keys as K
from gcnt.envs.benchmark import get_benchmark
from gcnt.envs.robot_table import robot_table
from gcnt.nn import count_parameters, make_network
from gcnt.nn.synthetic import random_robots, smpenv_like_robots

log = logging.getLogger(__name__)

#: methods per benchmark, in the paper's column order
METHODS = {
    "smpenv": (
        "smp",
        "amorpheus",
        "swat",
        "gcnt",
        "gcnt_no_gcn",
        "gcnt_no_wl",
        "gcnt_no_dist",
        "sr",
    ),
    "unimal": ("metamorph", "metamorph_star", "modumorph", "gcnt", "gcnt_hn", "sr"),
}
#: the original SMP code's both-way actor (F = 19, message 32), by number of child slots
SMP_ORIGINAL_ACTOR = {2: 323_781, 4: 347_141}
#: the algorithm whose actor/critic the paper trains on each benchmark
ALGORITHM = {"smpenv": "td3", "unimal": "ppo"}
#: which of our counts the paper's number is closest to: UNIMAL's are actor + critic; SMPENV's
#: are at most one actor
COMPARED = {"smpenv": "actor", "unimal": "total"}

#: the paper's appendix table 7 (SMPENV) and table 8 (UNIMAL, per world)
PAPER: dict[str, dict[str, dict[str, int]]] = {
    "smpenv": {
        "": {"smp": 694_410, "amorpheus": 202_389, "swat": 202_397, "gcnt": 206_613},
    },
    "unimal": {
        "FT": {
            "metamorph": 3_318_147,
            "metamorph_star": 3_315_075,
            "modumorph": 5_232_774,
            "gcnt": 3_333_583,
        },
        "Incline": {
            "metamorph": 3_318_147,
            "metamorph_star": 3_315_075,
            "modumorph": 5_232_774,
            "gcnt": 3_333_583,
        },
        "MT": {
            "metamorph": 3_531_587,
            "metamorph_star": 3_528_515,
            "modumorph": 8_608_262,
            "gcnt": 3_553_523,
        },
        "Obstacles": {
            "metamorph": 3_539_907,
            "metamorph_star": 3_536_835,
            "modumorph": 9_689_862,
            "gcnt": 3_561_843,
        },
    },
}
#: world names as benchmark records may spell them -> the paper's column
_PAPER_WORLD = {
    "ft": "FT",
    "flat": "FT",
    "incline": "Incline",
    "mt": "MT",
    "obstacles": "Obstacles",
}

#: the UNIMAL contract, used while no "unimal" benchmark record is registered
UNIMAL_FALLBACK = dict(
    limb_obs_dim=52,
    action_slots=2,
    worlds=("FT", "Incline", "MT", "Obstacles"),
    hfield_worlds=("MT", "Obstacles"),
    hfield_dim=1410,
    decoder_hidden={"MT": (64,), "Obstacles": (64, 64)},
)
#: UNIMAL robot tables: 12 limb slots, 35 context numbers per limb
UNIMAL_MAX_LIMBS = 12
UNIMAL_CONTEXT_DIM = 35


@dataclass(frozen=True)
class Setup:
    benchmark: str
    preset: str
    obs_dim: int
    num_actions: int
    #: (world, height-map width) pairs; one ("", 0) for a benchmark without worlds
    worlds: tuple[tuple[str, int], ...]
    #: the limb decoder's hidden widths per world (a world not listed: the networks' default)
    decoder_hidden: Mapping[str, tuple[int, ...]] = field(default_factory=dict)


def setup_of(benchmark: str) -> Setup:
    """Widths and worlds of ``benchmark`` from its record (UNIMAL: the contract's numbers while
    no record is registered)."""
    try:
        b = get_benchmark(benchmark)
    except ValueError:
        if benchmark != "unimal":
            raise
        log.warning("no 'unimal' benchmark record registered: using F=52, A=2, height map 1410")
        f = UNIMAL_FALLBACK
        worlds = tuple((w, f["hfield_dim"] if w in f["hfield_worlds"] else 0) for w in f["worlds"])
        return Setup(
            "unimal", "unimal", f["limb_obs_dim"], f["action_slots"], worlds, f["decoder_hidden"]
        )
    worlds = tuple((w, b.hfield_dim if w in b.hfield_worlds else 0) for w in b.worlds) or (("", 0),)
    return Setup(b.name, b.preset, b.limb_obs_dim, b.action_slots, worlds, b.decoder_hidden)


def counting_table(setup: Setup):
    """A robot table with the benchmark's padding (and a zero context for UNIMAL)."""
    if setup.benchmark == "smpenv":
        return robot_table(smpenv_like_robots(), None, setup.num_actions)
    table = robot_table(random_robots([12, 7, 9, 10], seed=0), UNIMAL_MAX_LIMBS, setup.num_actions)
    table.set(K.CONTEXT, torch.zeros(*table.batch_size, UNIMAL_MAX_LIMBS, UNIMAL_CONTEXT_DIM))
    return table


def network_kwargs(setup: Setup, table, hfield: int, world: str = "") -> dict:
    """What :func:`gcnt.nn.make_network` takes, besides method and role, at ``setup``'s widths
    in ``world``."""
    kw = dict(
        table=table,
        obs_dim=setup.obs_dim,
        num_actions=setup.num_actions,
        preset=setup.preset,
        hfield_dim=hfield,
    )
    if world in setup.decoder_hidden:
        kw["decoder_hidden"] = setup.decoder_hidden[world]
    return kw


def count_table(
    benchmark: str = "smpenv",
    sizes: Callable[[str], dict] | None = None,
    worlds: Sequence[str] | None = None,
    methods: Sequence[str] | None = None,
) -> list[dict]:
    """One row per (world, method): actor, critic, their sum and the paper's number (or None).

    ``sizes(method)``: that method's overrides of the preset (a recipe's ``network.kwargs``),
    default none (the paper's sizes); ``worlds``: only these (case-insensitive); ``methods``:
    instead of the benchmark's column list."""
    setup = setup_of(benchmark)
    algo = ALGORITHM.get(setup.benchmark, "ppo")
    table = counting_table(setup)
    paper = PAPER.get(setup.benchmark, {})
    wanted = None if worlds is None else {w.lower() for w in worlds}
    rows = []
    for world, hfield in setup.worlds:
        if wanted is not None and world.lower() not in wanted:
            continue
        col = paper.get(_PAPER_WORLD.get(world.lower(), world), {})
        kw = network_kwargs(setup, table, hfield, world)
        for name in methods or METHODS.get(setup.benchmark, METHODS["unimal"]):
            over = sizes(name) if sizes is not None else {}
            actor = count_parameters(make_network(name, f"{algo}_actor", **kw, **over))
            critic = count_parameters(make_network(name, f"{algo}_critic", **kw, **over))
            rows.append(
                {
                    "world": world,
                    "method": name,
                    "actor": actor,
                    "critic": critic,
                    "total": actor + critic,
                    "paper": col.get(name),
                }
            )
    return rows


#: (label, numerator, denominator) of the size ratios that decide whether a comparison is fair
RATIOS = (
    ("ModuMorph/GCNT", "modumorph", "gcnt"),
    ("MetaMorph/GCNT", "metamorph", "gcnt"),
    ("GCNT/MetaMorph*", "gcnt", "metamorph_star"),
    ("GCNT/AMORPHEUS", "gcnt", "amorpheus"),
)


def ratios(rows: list[dict], world: str) -> dict[str, tuple[float, float | None]]:
    """The :data:`RATIOS` of the methods in ``rows`` (actor + critic), ours and the paper's."""
    by = {r["method"]: r for r in rows if r["world"] == world}
    out = {}
    for label, a, b in RATIOS:
        if a in by and b in by:
            pa, pb = by[a]["paper"], by[b]["paper"]
            out[label] = (by[a]["total"] / by[b]["total"], pa / pb if pa and pb else None)
    return out
