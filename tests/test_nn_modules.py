"""Single stages against hand computations; ablation switches; the graph lookup; SWAT/SMP parts."""

from __future__ import annotations

import math

import pytest
import torch
from nn_helpers import F_OBS, batch, double, robots, small, table_of

from gcnt.envs.robot_table import RobotTooLargeError
from gcnt.morphology import GLOBAL_LIMB_TYPES
from gcnt.nn import GCNTConfig, count_parameters, graph_lookup_of, make_network
from gcnt.nn.baselines.smp import SMPUp, tree_depth
from gcnt.nn.layers import EncoderLayer, key_padding_bias
from gcnt.nn.stages import DistanceBias, LimbGCN, normalized_adjacency
from gcnt.nn.synthetic import random_robots, tree_robot

# ------------------------------------------------------------------------------------ GCN


def test_gcn_layer_matches_hand_computation_on_a_3_limb_chain():
    # chain 0 - 1 - 2 with two padded slots whose adjacency is deliberately dirty
    adj = torch.zeros(1, 5, 5, dtype=torch.bool)
    for i, j in [(0, 1), (1, 2), (2, 3), (1, 4)]:
        adj[0, i, j] = adj[0, j, i] = True
    mask = torch.tensor([[True, True, True, False, False]])
    types = torch.tensor([[0, 1, 2, 5, 6]])
    # Â by hand: degrees of A + I over the real limbs are 2, 3, 2
    s6 = 1 / math.sqrt(6)
    a_hat = torch.tensor([[1 / 2, s6, 0], [s6, 1 / 3, s6], [0, s6, 1 / 2]])
    torch.testing.assert_close(normalized_adjacency(adj, mask)[0, :3, :3], a_hat)
    assert (normalized_adjacency(adj, mask)[0, 3:] == 0).all()
    assert (normalized_adjacency(adj, mask)[0, :, 3:] == 0).all()

    gcn = LimbGCN(num_types=7, width=2, layers=1)
    with torch.no_grad():
        gcn.embed.weight.copy_(torch.tensor([[1.0, 0, 0, 0, 0, 0, 0], [0, 1.0, 2.0, 0, 0, 0, 0]]))
        layer = gcn.layers[0]
        layer.w1.weight.copy_(torch.tensor([[1.0, -1.0], [2.0, 0.5]]))
        layer.w1.bias.copy_(torch.tensor([0.1, -0.2]))
        layer.w2.weight.copy_(torch.tensor([[0.5, 1.0], [-1.0, 0.0]]))
        layer.w2.bias.copy_(torch.tensor([0.0, 0.3]))
    # H⁰ rows: one-hot(type) @ embedᵀ: type 0 → (1, 0), type 1 → (0, 1), type 2 → (0, 2)
    h0 = torch.tensor([[1.0, 0.0], [0.0, 1.0], [0.0, 2.0]])
    agg = a_hat @ h0
    pre = agg @ torch.tensor([[1.0, -1.0], [2.0, 0.5]]).T + torch.tensor([0.1, -0.2])
    expected = (
        torch.relu(pre) @ torch.tensor([[0.5, 1.0], [-1.0, 0.0]]).T + torch.tensor([0.0, 0.3]) + h0
    )
    out = gcn(types, adj, mask)
    torch.testing.assert_close(out[0, :3], expected)
    assert (out[0, 3:] == 0).all()


def test_gcn_padding_does_not_leak_even_with_dirty_padded_adjacency():
    gcn = LimbGCN(7, 4, 4)
    adj = torch.zeros(2, 4, 4, dtype=torch.bool)
    adj[:, 0, 1] = adj[:, 1, 0] = True
    mask = torch.tensor([[True, True, False, False]] * 2)
    types = torch.tensor([[0, 1, 3, 4], [0, 1, 6, 2]])  # padded types differ
    adj[1, 1, 2] = adj[1, 2, 1] = adj[1, 3, 3] = True  # dirty padding in sample 1
    out = gcn(types, adj, mask)
    torch.testing.assert_close(out[0], out[1])


# -------------------------------------------------------------------------- distance bias


def test_distance_bias_shapes_and_clamping():
    bias = DistanceBias(max_dist=3, heads=2, tables=4)
    with torch.no_grad():
        bias.embed.weight.copy_(torch.arange(4 * 8, dtype=torch.float32).view(4, 8))
    dist = torch.tensor([[[0, 1], [2, 255]]], dtype=torch.uint8).expand(5, 2, 2)
    out = bias(dist)
    assert out.shape == (5, 4, 2, 2, 2)
    # layer t, head h, pair (i, j) reads row clamp(d_ij) column t * heads + h
    assert out[0, 1, 0, 0, 1] == 1 * 8 + 1 * 2 + 0
    assert out[0, 3, 1, 1, 1] == 3 * 8 + 3 * 2 + 1  # 255 clamped to 3


def test_distance_bias_changes_attention():
    """A bias of -1e4 on every non-self pair makes each limb attend only to itself: its features
    then do not depend on the other limbs' observations (a zero Jacobian block, exactly);
    without the bias they do. float64, structural."""
    torch.manual_seed(0)
    rs = robots()
    table = table_of(rs)
    net = make_network(
        "gcnt",
        "td3_actor",
        table=table,
        obs_dim=F_OBS,
        num_actions=1,
        keep_intermediates=True,
        **small("gcnt"),
    ).double()
    td = double(batch(table, [3], seed=0))  # walker_7

    # a random projection of the features: their plain sum is constant under the final
    # LayerNorm (its gradient is 0 up to rounding, whatever the attention does)
    def dependence():
        """|d (features[limbs 0-3] · random weights) / d obs[limbs 4-6]| summed."""
        obs = td["limbs", "obs"].clone().requires_grad_()
        x = td.clone()
        x.set(("limbs", "obs"), obs)
        feats = net(x)["limbs", "features"][:, :4]
        weights = torch.randn(feats.shape, generator=torch.Generator().manual_seed(1)).double()
        (feats * weights).sum().backward()
        return obs.grad[:, 4:7].abs().sum()

    assert dependence() > 0  # attention mixes limbs
    with torch.no_grad():
        w = net["dist_bias"].module.embed.weight
        w.fill_(-1e4)
        w[0].zero_()  # distance 0 (self) unbiased
    assert dependence() == 0  # only self attended


def test_encoder_layer_bias_equals_manual_attention():
    """The SDPA path with an additive mask equals a hand-written softmax(qk/√d + bias)."""
    torch.manual_seed(1)
    layer = EncoderLayer(8, 2, 16).double()
    x = torch.randn(3, 5, 8, dtype=torch.float64)
    mask = torch.tensor([[1, 1, 1, 0, 0], [1, 1, 1, 1, 1], [1, 0, 0, 0, 0]], dtype=torch.bool)
    bias = torch.randn(3, 2, 5, 5, dtype=torch.float64)
    m = key_padding_bias(mask, x.dtype) + bias
    got = layer.attention(x, m)
    q, k, v = layer.qkv(x).view(3, 5, 3, 2, 4).permute(2, 0, 3, 1, 4)
    w = torch.softmax(q @ k.transpose(-1, -2) / 2.0 + m, -1)
    want = layer.proj((w @ v).transpose(1, 2).reshape(3, 5, 8))
    torch.testing.assert_close(got, want, atol=1e-12, rtol=0)


# ------------------------------------------------------------------------------ ablations


def _names(net) -> list[str]:
    return [n for n, _ in net.named_parameters()]


def test_ablation_switches_remove_their_parameters():
    table = table_of(robots())
    kw = dict(table=table, obs_dim=F_OBS, num_actions=1)
    cfg = GCNTConfig.preset("smpenv")
    full = make_network("gcnt", "td3_actor", **kw)
    no_gcn = make_network("gcnt_no_gcn", "td3_actor", **kw)
    no_wl = make_network("gcnt", "td3_actor", use_wl=False, **kw)
    no_dist = make_network("gcnt_no_dist", "td3_actor", **kw)
    none = make_network("gcnt", "td3_actor", use_gcn=False, use_wl=False, use_dist_bias=False, **kw)
    amorpheus = make_network("amorpheus", "td3_actor", **kw)
    n = count_parameters
    g, w, d = cfg.gcn_width, table["graph", "wl"].shape[-1], cfg.d_model
    gcn_params = len(GLOBAL_LIMB_TYPES) * g + cfg.gcn_layers * 2 * (g * g + g)
    assert n(full) - n(no_gcn) == gcn_params + g * d  # GCN + its share of the projection
    assert n(full) - n(no_wl) == w * d
    assert n(full) - n(no_dist) == (cfg.max_dist + 1) * cfg.heads  # one table for all layers
    assert n(none) == n(amorpheus)
    assert not any("gcn" in p for p in _names(no_gcn))
    assert not any("dist_bias" in p for p in _names(no_dist))
    assert not any("fusion" in p for p in _names(none))


# ----------------------------------------------------------------------------- lookup


def test_state_dict_has_no_table_and_loads_into_other_robots():
    rs = robots()
    train = make_network(
        "gcnt", "td3_actor", table=table_of(rs[:10]), obs_dim=F_OBS, num_actions=1, **small("gcnt")
    )
    assert not any("table" in k for k in train.state_dict())
    # zero-shot: a network built for other robots (and another padding) loads the weights
    other = table_of(rs[20:], k=12)
    test = make_network(
        "gcnt", "td3_actor", table=other, obs_dim=F_OBS, num_actions=1, **small("gcnt")
    )
    test.load_state_dict(train.state_dict())
    td = batch(other, [0, 1, 2], seed=5)
    # the trained net with its table swapped gives the same actions
    graph_lookup_of(train).set_table(other)
    torch.testing.assert_close(
        train(td.clone())["limbs", "action"], test(td.clone())["limbs", "action"]
    )


def test_lookup_restores_static_keys_and_checks_sizes():
    rs = robots()
    table = table_of(rs)
    net = make_network(
        "gcnt",
        "td3_actor",
        table=table,
        obs_dim=F_OBS,
        num_actions=1,
        keep_intermediates=True,
        **small("gcnt"),
    )
    td = batch(table, [4, 7], seed=0)
    out = net(td)
    for key in (("limbs", "mask"), ("graph", "dist"), ("graph", "wl"), ("graph", "adj")):
        torch.testing.assert_close(out[key], table[key][torch.tensor([4, 7])])
    wrong_k = batch(table_of(rs, k=12), [0], seed=0)
    with pytest.raises(ValueError, match="12 limb slots"):
        net(wrong_k)
    with pytest.raises(IndexError, match="morph_id"):
        net(batch(table, [len(rs)], seed=0))


def test_lookup_follows_device_and_dtype_moves():
    table = table_of(robots())
    net = make_network(
        "amorpheus", "td3_critic", table=table, obs_dim=F_OBS, num_actions=1, **small("amorpheus")
    )
    net = net.to("meta")
    lookup = graph_lookup_of(net)
    assert all(b.device.type == "meta" for b in lookup.buffers())
    lookup.set_table(table)  # a swapped table lands on the module's device
    assert all(b.device.type == "meta" for b in lookup.buffers())


# ------------------------------------------------------------------------------ SWAT


def test_swat_rejects_a_robot_larger_than_its_position_tables():
    rs = list(robots())
    big = tree_robot([-1, 0, 1, 2, 0, 4, 5, 0, 7, 8], name="walker_ten")
    with pytest.raises(RobotTooLargeError, match=r"walker_ten.*10 limbs.*SWAT.*at most 9"):
        make_network(
            "swat",
            "td3_actor",
            table=[*rs, big],
            obs_dim=F_OBS,
            num_actions=1,
            pad_limbs=10,
            **{**small("swat"), "max_limbs": 9},
        )
    net = make_network(
        "swat",
        "td3_actor",
        table=table_of(rs),
        obs_dim=F_OBS,
        num_actions=1,
        **{**small("swat"), "max_limbs": 9},
    )
    with pytest.raises(RobotTooLargeError, match="morph_id=.*10 limbs"):
        graph_lookup_of(net).set_table(table_of([*rs, big]))


def test_swat_relational_bias_only_in_first_layer():
    net = make_network(
        "swat", "td3_actor", table=table_of(robots()), obs_dim=F_OBS, num_actions=1, **small("swat")
    )
    assert net["transformer"].module.encoder.bias_mode == "first"
    assert net["relational_bias"].module.lin.weight.shape == (2, 3)


# ------------------------------------------------------------------------------ SMP


def test_tree_depth():
    parent = torch.tensor([[-1, 0, 1, 0, 3, -1, -1]])
    mask = torch.tensor([[True] * 5 + [False] * 2])
    assert tree_depth(parent, mask).tolist() == [[0, 1, 2, 1, 2, -1, -1]]


def test_smp_up_messages_see_only_the_subtree():
    """Limb i's up-message depends on limb j's input exactly when j is in i's subtree: the
    Jacobian block d up_i / d x_j is non-zero there and exactly zero elsewhere (float64; a
    structural check, not a finite difference that rounding can hide)."""
    torch.manual_seed(0)
    robot = random_robots([8], seed=7)[0]
    table = table_of([robot])
    parent, mask = table["graph", "parent"], table["limbs", "mask"]
    up = SMPUp(F_OBS, 8, 12).double()
    x = torch.randn(1, 8, F_OBS, dtype=torch.float64)
    jac = torch.autograd.functional.jacobian(lambda v: up(v, parent, mask), x)
    # jac: [1, K, msg, 1, K, F]; depends[i, j]: up_i depends on x_j
    depends = jac[0, :, :, 0].abs().sum((1, 3)) > 0
    kids = {i: [j for j in range(8) if parent[0, j] == i] for i in range(8)}

    def subtree(i):
        out = {i}
        for c in kids[i]:
            out |= subtree(c)
        return out

    for i in range(8):
        assert set(depends[i].nonzero().flatten().tolist()) == subtree(i)


def test_one_distance_table_shared_by_all_layers_by_default():
    """Eq. 5: one g_φ(d) per head, used by every layer; per-layer tables are an option."""
    table = table_of(robots())
    kw = dict(table=table, obs_dim=F_OBS, num_actions=1, layers=3, heads=2)
    shared = make_network("gcnt", "td3_actor", **kw)
    per_layer = make_network("gcnt", "td3_actor", dist_bias="per_layer", **kw)
    assert shared["dist_bias"].module.embed.weight.shape == (16, 2)
    assert per_layer["dist_bias"].module.embed.weight.shape == (16, 3 * 2)
    assert shared["transformer"].module.encoder.bias_mode == "shared"


@pytest.mark.parametrize("length", [1, 5, 32])  # 32: the longest on the matmul path
def test_attention_equals_torch_sdpa_with_its_gradients(length):
    """The short-sequence path of ``layers.attention`` computes torch's scaled_dot_product_attention
    (float64: values and the gradients of q, k, v and a learned bias, padded keys at -inf)."""
    from gcnt.nn.layers import attention, key_padding_bias

    g = torch.Generator().manual_seed(0)
    n, h, d = 7, 2, 4
    q, k, v = (torch.randn(n, h, length, d, generator=g, dtype=torch.float64) for _ in range(3))
    bias = torch.randn(n, h, length, length, generator=g, dtype=torch.float64)
    mask = torch.ones(n, length, dtype=torch.bool)
    mask[: n // 2, (length + 1) // 2 :] = False  # padded limbs on half the samples
    results = []
    for fn in (attention, torch.nn.functional.scaled_dot_product_attention):
        leaves = [t.clone().requires_grad_() for t in (q, k, v, bias)]
        m = key_padding_bias(mask, torch.float64) + leaves[3]
        out = fn(leaves[0], leaves[1], leaves[2], attn_mask=m)
        out.backward(
            torch.randn(out.shape, generator=torch.Generator().manual_seed(1), dtype=out.dtype)
        )
        results.append([out.detach(), *(t.grad for t in leaves)])
    for mine, torch_ in zip(*results, strict=True):
        torch.testing.assert_close(mine, torch_, rtol=1e-10, atol=1e-12)
