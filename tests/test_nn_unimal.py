"""The network seam (registering a method from outside gcnt, the height-map input, the PPO std
as make_network arguments) and the UNIMAL methods' parts: MetaMorph(*) init and positions,
ModuMorph's hypernetwork and fixed attention, GCNT+HN, parameter counts against the originals."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import pytest
import torch
from nn_helpers import (
    A_UNIMAL,
    C_UNIMAL,
    F_UNIMAL,
    H_SMALL,
    UNIMAL_NAMES,
    batch,
    double,
    small,
    unimal_robots,
    unimal_table,
)
from tensordict.nn import TensorDictModule
from torch import nn

from gcnt import keys as K
from gcnt.nn import (
    Backbone,
    GCNTConfig,
    NetConfig,
    NetIO,
    count_parameters,
    graph_lookup_of,
    limb_mean,
    make_network,
    register_network,
    unregister_network,
)
from gcnt.nn.layers import ContextAttentionLayer, HyperLinear, key_padding_bias
from gcnt.nn.stages import limb_head_stage

UNIMAL = dict(obs_dim=F_UNIMAL, num_actions=A_UNIMAL)

# ---------------------------------------------------------------------------- the seam


@dataclass
class ToyConfig(NetConfig):
    """A per-limb MLP: the smallest method."""

    width: int = 8


def build_toy(cfg: ToyConfig, io: NetIO, table) -> Backbone:
    enc = TensorDictModule(nn.Linear(io.in_dim, cfg.width), [K.INPUT], [K.FEATURES])
    head = limb_head_stage(cfg.width, io.out_dim, hfield_width=io.hfield_width)
    return Backbone([("encoder", enc), ("head", head)], name="Toy")


@pytest.fixture
def toy():
    register_network("toy_test_method", ToyConfig, build_toy)
    yield "toy_test_method"
    unregister_network("toy_test_method")


@pytest.mark.parametrize("role", ["td3_actor", "td3_critic", "ppo_actor", "ppo_critic"])
def test_a_method_registered_from_outside_builds_for_every_role(toy, role):
    table = unimal_table()
    net = make_network(toy, role, table=table, hfield_dim=H_SMALL, width=4, **UNIMAL)
    td = batch(table, [0, 1], f=F_UNIMAL, hfield=H_SMALL)
    chain = net[0] if role == "ppo_actor" else net
    out = chain(td)
    assert K.OUT not in out.keys(True)  # intermediates dropped
    assert "hfield" in chain.in_keys
    with pytest.raises(ValueError, match="already registered"):
        register_network(toy, ToyConfig, build_toy)
    with pytest.raises(ValueError, match="unknown ToyConfig field 'widht'.*did you mean 'width'"):
        make_network(toy, role, table=table, widht=3, **UNIMAL)


def test_a_method_that_ignores_the_height_map_is_refused(toy):
    def no_hfield(cfg, io, table):
        return build_toy(cfg, NetIO(io.in_dim, io.out_dim, 0), table)

    register_network("toy_no_hfield", ToyConfig, no_hfield)
    try:
        make_network("toy_no_hfield", "ppo_critic", table=unimal_table(), **UNIMAL)  # fine
        with pytest.raises(ValueError, match="Toy does not read the height map"):
            make_network(
                "toy_no_hfield", "ppo_critic", table=unimal_table(), hfield_dim=9, **UNIMAL
            )
    finally:
        unregister_network("toy_no_hfield")


def test_ppo_std_is_a_make_network_argument_not_a_config_field():
    table = unimal_table()
    kw = dict(table=table, **UNIMAL, **small("gcnt"))
    learned = make_network("gcnt", "ppo_actor", ppo_std="learned", ppo_init_std=0.5, **kw)
    log_std = [p for n, p in learned.named_parameters() if "log_std" in n]
    assert len(log_std) == 1 and torch.allclose(log_std[0].exp(), torch.tensor(0.5))
    with pytest.raises(ValueError, match="unknown GCNTConfig field 'ppo_std'"):
        GCNTConfig.preset("unimal", ppo_std="fixed")
    with pytest.raises(ValueError, match="ppo_init_std must be > 0"):
        make_network("gcnt", "ppo_actor", ppo_init_std=0.0, **kw)


@pytest.mark.parametrize("name", UNIMAL_NAMES)
def test_height_map_reaches_every_limb_of_every_method(name):
    table = unimal_table()
    net = make_network(
        name, "ppo_critic", table=table, hfield_dim=H_SMALL, **UNIMAL, **small(name)
    ).double()
    td = double(batch(table, [0, 2], f=F_UNIMAL, hfield=H_SMALL))
    h = td["hfield"].clone().requires_grad_()
    td.set("hfield", h)
    out = net(td)["limbs", "state_value"]
    mask = table["limbs", "mask"][td["morph_id"]]
    for b, limb in mask.nonzero().tolist():  # every real limb's value depends on its height map
        (g,) = torch.autograd.grad(out[b, limb].sum(), h, retain_graph=True)
        assert g[b].abs().sum() > 0 and (g[1 - b] == 0).all()


def test_critic_value_is_the_mean_over_real_limbs():
    table = unimal_table()
    net = make_network("metamorph_star", "ppo_critic", table=table, **UNIMAL, **small("metamorph"))
    out = net(batch(table, [0, 1, 3], f=F_UNIMAL))
    mask = table["limbs", "mask"][torch.tensor([0, 1, 3])]
    torch.testing.assert_close(out["state_value"], limb_mean(out["limbs", "state_value"], mask))


# ------------------------------------------------------------------------- MetaMorph


def test_metamorph_init_dropout_and_positions():
    table = unimal_table()
    net = make_network("metamorph", "ppo_actor", table=table, **UNIMAL, preset="unimal")
    chain = net[0]
    enc = chain["encoder"].module.net[0]
    head = chain["head"].module.net[-1]
    assert enc.weight.abs().max() <= 0.1
    assert head.weight.abs().max() <= 0.01 and (head.bias == 0).all()
    assert chain["position"].module.pe.shape == (12, 128)
    assert chain["position"].module.drop.p == 0.1
    layer = chain["transformer"].module.encoder.layers[0]
    assert layer.norm_first and chain["transformer"].module.encoder.norm is None
    star = make_network("metamorph_star", "ppo_actor", table=table, **UNIMAL, preset="unimal")
    assert "position" not in star[0].module
    assert not any(isinstance(m, nn.Dropout) and m.p > 0 for m in star.modules())
    with pytest.raises(ValueError, match="fixes position_embedding=False"):
        make_network("metamorph_star", "ppo_actor", table=table, position_embedding=True, **UNIMAL)


def test_metamorph_rejects_robots_beyond_its_position_table():
    from gcnt.envs.robot_table import RobotTooLargeError

    with pytest.raises(RobotTooLargeError, match="MetaMorph allows at most 5"):
        make_network(
            "metamorph",
            "ppo_actor",
            table=unimal_table(),
            max_limbs=5,
            **UNIMAL,
            **small("metamorph"),
        )


# ------------------------------------------------------------------------- ModuMorph


def test_hyper_linear_is_a_per_limb_linear_map():
    torch.manual_seed(0)
    lin = HyperLinear(ctx_dim=3, in_dim=4, out_dim=2, weight_bound=0.1).double()
    x = torch.randn(5, 6, 4, dtype=torch.float64)
    h = torch.randn(5, 6, 3, dtype=torch.float64)
    # at init the generators' weights are zero: the same map for every limb
    shared = lin.weight.bias.view(4, 2)
    torch.testing.assert_close(lin(x, h), x @ shared, atol=1e-12, rtol=0)
    with torch.no_grad():
        for p in lin.parameters():
            p.normal_()
    w = lin.weight(h).view(5, 6, 4, 2)
    want = (x.unsqueeze(-2) @ w).squeeze(-2) + lin.bias(h)
    torch.testing.assert_close(lin(x, h), want, atol=1e-12, rtol=0)


def test_fixed_attention_weights_come_from_the_context_only():
    """The attention pattern depends on the context, not on the tokens: the output is
    x + proj(A · V(LN(x))) + FF, with A computed from the context alone (float64)."""
    torch.manual_seed(0)
    layer = ContextAttentionLayer(8, 2, 16).double()
    x = torch.randn(3, 5, 8, dtype=torch.float64)
    ctx = torch.randn(3, 5, 8, dtype=torch.float64)
    mask = torch.tensor([[1, 1, 1, 0, 0], [1, 1, 1, 1, 1], [1, 1, 0, 0, 0]], dtype=torch.bool)
    m = key_padding_bias(mask, x.dtype)
    w, b = layer.qkv.weight, layer.qkv.bias
    c = layer.norm_ctx(ctx)
    q = (c @ w[:8].T + b[:8]).view(3, 5, 2, 4).transpose(1, 2)
    k = (c @ w[8:16].T + b[8:16]).view(3, 5, 2, 4).transpose(1, 2)
    a = torch.softmax(q @ k.transpose(-1, -2) / 2.0 + m, -1)
    v = (layer.norm1(x) @ w[16:].T + b[16:]).view(3, 5, 2, 4).transpose(1, 2)
    y = x + layer.proj((a @ v).transpose(1, 2).reshape(3, 5, 8))
    want = y + layer.feed_forward(layer.norm2(y))
    torch.testing.assert_close(layer(x, ctx, m), want, atol=1e-12, rtol=0)


@pytest.mark.parametrize("name", ["modumorph", "gcnt_hn"])
def test_hypernetwork_methods_need_the_limb_context(name):
    from gcnt.envs.robot_table import robot_table

    bare = robot_table(list(unimal_robots()), None, A_UNIMAL)
    with pytest.raises(ValueError, match=r"\('limbs', 'context'\)"):
        make_network(name, "ppo_actor", table=bare, **UNIMAL, **small(name))
    net = make_network(name, "ppo_actor", table=unimal_table(), **UNIMAL, **small(name))
    assert ("limbs", "context") in graph_lookup_of(net).keys
    # the table swap for zero-shot evaluation needs it too
    with pytest.raises(KeyError, match="lacks the static keys"):
        graph_lookup_of(net).set_table(bare)


@pytest.mark.parametrize("name", ["modumorph", "gcnt_hn"])
def test_limbs_with_another_context_get_other_weights(name):
    """The encoder/decoder maps are per limb: two limbs with equal inputs but different contexts
    get different embeddings once the generators have non-zero weights."""
    torch.manual_seed(0)
    table = unimal_table()
    net = make_network(
        name, "ppo_critic", table=table, keep_intermediates=True, **UNIMAL, **small(name)
    ).double()
    with torch.no_grad():
        for p in net["encoder"].parameters():
            p.normal_()
    td = double(batch(table, [0], f=F_UNIMAL))
    td["limbs", "obs"][0, 1] = td["limbs", "obs"][0, 2]
    emb = net(td)["limbs", "embed"][0]
    assert not torch.allclose(emb[1], emb[2])


# ------------------------------------------------------------------- parameter counts


def test_unimal_parameter_counts_match_the_original_models():
    """MetaMorph / MetaMorph* at 52 inputs: the public code's count (the paper's table is 2,560
    higher: 62 inputs). ModuMorph: the paper's table minus the modules its code builds but never
    uses (a plain embedding and decoder per network). Ratios as in the paper."""
    from gcnt.analysis import params as counts

    rows = {(r["world"], r["method"]): r["total"] for r in counts.count_table("unimal")}
    worlds = {w for w, _ in rows}
    ft = next(w for w in worlds if w.lower() in ("ft", "flat"))
    mt = next(w for w in worlds if w.lower() == "mt")
    assert rows[ft, "metamorph"] == 3_318_147 - 2_560
    assert rows[ft, "metamorph_star"] == 3_315_075 - 2_560
    assert rows[mt, "metamorph"] == 3_531_587 - 2_560
    assert rows[ft, "modumorph"] == 5_232_774 - (2 * 6_784 + 258 + 129)
    assert rows[mt, "modumorph"] == 8_608_262 - (2 * 6_784 + 12_482 + 12_417)
    # Obstacles' decoder has two hidden layers of 64 (MT: one): 2 x (64 x 64 + 64) = 8,320 more
    # per method, and ModuMorph's unused plain decoder grows by as much
    obs = next(w for w in worlds if w.lower() == "obstacles")
    assert rows[obs, "metamorph"] == 3_539_907 - 2_560
    assert rows[obs, "metamorph_star"] == 3_536_835 - 2_560
    assert rows[obs, "modumorph"] == 9_689_862 - (2 * 6_784 + 12_482 + 12_417 + 8_320)
    for method in ("metamorph", "metamorph_star", "gcnt"):  # plain decoders: one Linear(64→64)
        assert rows[obs, method] - rows[mt, method] == 8_320
    # GCNT adds about 1% to MetaMorph*; ModuMorph is 1.6x (FT) to 2.4x (MT) GCNT
    assert 1.0 < rows[ft, "gcnt"] / rows[ft, "metamorph_star"] < 1.015
    assert 1.5 < rows[ft, "modumorph"] / rows[ft, "gcnt"] < 1.6
    assert 2.35 < rows[mt, "modumorph"] / rows[mt, "gcnt"] < 2.45


def test_params_command_unimal(capsys):
    from gcnt.commands import params

    params.run(argparse.Namespace(benchmark="unimal"))
    out = capsys.readouterr().out
    for text in ("metamorph_star", "modumorph", "gcnt_hn", "ModuMorph/GCNT", "GCNT/MetaMorph*"):
        assert text in out
    assert "3,315,075" in out  # the paper's number is printed next to ours


def test_context_width_is_read_from_the_table():
    table = unimal_table()
    assert table["limbs", "context"].shape[-1] == C_UNIMAL
    net = make_network("modumorph", "ppo_critic", table=table, **UNIMAL, **small("modumorph"))
    assert net["hn_context"].module.net[0].in_features == C_UNIMAL
    assert count_parameters(net) > 0


def test_params_command_at_a_recipes_sizes_compares_the_ratios_with_the_papers_sizes(capsys):
    """The re-run UNIMAL study keeps the paper's proportions (within 10%); the first study's
    reduction did not (ModuMorph / GCNT 3.04 against 1.56)."""
    from gcnt.commands import params

    root = Path(__file__).resolve().parents[1] / "recipes" / "studies"
    methods = "gcnt,modumorph,metamorph"
    params.run_recipe(str(root / "ft-fair.yaml"), methods)
    fair = capsys.readouterr().out
    assert "ModuMorph/GCNT (actor + critic): 1.473" in fair
    assert "NOT within" not in fair and fair.count("within 10%") == 2
    params.run_recipe(str(root / "ft.yaml"), methods)
    first = capsys.readouterr().out
    assert "ModuMorph/GCNT (actor + critic): 3.041" in first and "NOT within 10%" in first


@pytest.mark.parametrize("name", ["gcnt", "gcnt_hn", "metamorph", "modumorph", "amorpheus", "swat"])
def test_transformer_layers_start_as_copies_of_one_layer(name):
    """Every original builds its stack with torch's ``_get_clones`` (deep copies of one layer),
    so the layers are equal at initialisation (and train apart)."""
    from gcnt.nn.layers import ContextTransformer, TransformerEncoder

    table = unimal_table() if name in ("gcnt", "gcnt_hn", "metamorph", "modumorph") else None
    kw = dict(table=table, **UNIMAL) if table is not None else {}
    if table is None:
        from nn_helpers import F_OBS, robots, table_of

        kw = dict(table=table_of(robots()), obs_dim=F_OBS, num_actions=1)
    net = make_network(name, "ppo_actor" if table is not None else "td3_actor", **kw, **small(name))
    stacks = [m for m in net.modules() if isinstance(m, (TransformerEncoder, ContextTransformer))]
    assert stacks
    for stack in stacks:
        assert len(stack.layers) >= 2
        first = stack.layers[0].state_dict()
        for layer in stack.layers[1:]:
            other = layer.state_dict()
            assert all(torch.equal(first[k], other[k]) for k in first)
            assert all(
                p.data_ptr() != q.data_ptr()
                for p, q in zip(stack.layers[0].parameters(), layer.parameters(), strict=True)
            )


def test_each_world_has_the_originals_decoder_depth():
    """``DECODER_DIMS``: none on FT and Incline (default), [64] on MT (configs/csr.yaml),
    [64, 64] on Obstacles (configs/obstacle.yaml); training builds its networks with them."""
    from gcnt.envs.benchmark import get_benchmark
    from gcnt.nn.layers import HyperLinear
    from gcnt.nn.stages import HyperHead, LimbHead

    hidden = get_benchmark("unimal").decoder_hidden
    assert hidden == {"ft": (), "incline": (), "mt": (64,), "obstacles": (64, 64)}
    table = unimal_table()
    for name in ("metamorph", "modumorph"):
        net = make_network(
            name, "ppo_critic", table=table, hfield_dim=H_SMALL, decoder_hidden=(64, 64),
            **UNIMAL, **small(name),
        )  # fmt: skip
        head = next(m for m in net.modules() if isinstance(m, (LimbHead, HyperHead)))
        kind = HyperLinear if name == "modumorph" else torch.nn.Linear
        assert sum(isinstance(m, kind) for m in head.modules()) == 3  # 2 hidden + output
