"""Points where gcnt follows the original code rather than PyTorch's or torchrl's defaults: where
GCNT's distance bias enters the encoder, MultiheadAttention's initial attention weights, ModuMorph's
context encoders, and PPO's critic loss (½ · max of the clipped and unclipped squared errors,
times VALUE_COEF), each against a hand computation or the original's numbers."""

from __future__ import annotations

import pytest
import torch
from nn_helpers import (
    A_UNIMAL,
    F_OBS,
    F_UNIMAL,
    batch,
    double,
    robots,
    small,
    table_of,
    unimal_table,
)
from tensordict import TensorDict

from gcnt.nn import make_config, make_network
from gcnt.nn.layers import ContextAttentionLayer, EncoderLayer
from gcnt.nn.stages import CONTEXT_EMBED_BOUND, ContextMLP


def _layers(net):
    return [m for m in net.modules() if isinstance(m, EncoderLayer)]


def _masks_per_layer(name: str, **overrides) -> list[torch.Tensor]:
    """The additive attention mask every encoder layer of a GCNT actor receives, with a random
    (non-zero) distance table, in float64."""
    torch.manual_seed(0)
    table = table_of(robots())
    net = make_network(
        name, "td3_actor", table=table, obs_dim=F_OBS, num_actions=1, **small("gcnt"), **overrides
    ).double()
    dist = net["dist_bias"].module
    with torch.no_grad():
        dist.embed.weight.normal_()
    seen: list[torch.Tensor] = []
    hooks = [
        layer.register_forward_pre_hook(lambda _m, args: seen.append(args[1].clone()))
        for layer in _layers(net)
    ]
    net(double(batch(table, [0, 1, 2, 5])))
    for h in hooks:
        h.remove()
    return seen


def test_dist_bias_first_changes_the_first_layers_attention_only():
    every = _masks_per_layer("gcnt")
    first = _masks_per_layer("gcnt_dist_first")
    assert len(every) == len(first) == small("gcnt")["layers"] == 2
    # "all": the one shared table in every layer
    assert torch.equal(every[0], every[1])
    # "first": the same bias in layer 0, only the key-padding mask (0 / -inf) after it
    assert torch.equal(first[0], every[0])
    plain = first[1]
    assert set(plain.unique().tolist()) <= {0.0, float("-inf")}
    assert not torch.equal(plain, every[1])


def test_dist_bias_layers_is_validated_and_first_is_the_registered_ablation():
    assert make_config("gcnt").dist_bias_layers == "all"
    assert make_config("gcnt_dist_first").dist_bias_layers == "first"
    with pytest.raises(ValueError, match="dist_bias_layers must be 'all' or 'first'"):
        make_config("gcnt", dist_bias_layers="last")
    with pytest.raises(ValueError, match="needs dist_bias='shared'"):
        make_config("gcnt", dist_bias="per_layer", dist_bias_layers="first")
    # the same parameters either way: only where the table enters differs
    a, b = (
        make_network(n, "td3_actor", table=table_of(robots()), obs_dim=F_OBS, num_actions=1)
        for n in ("gcnt", "gcnt_dist_first")
    )
    assert [p.shape for p in a.parameters()] == [p.shape for p in b.parameters()]


@pytest.mark.parametrize("name", ["gcnt", "amorpheus", "swat", "metamorph", "modumorph"])
def test_attention_starts_as_multihead_attention(name):
    """Every original uses nn.MultiheadAttention: xavier-uniform in-projection over [3d, d], zero
    in- and out-projection biases (the out-projection weight keeps Linear's default)."""
    torch.manual_seed(0)
    unimal = name in ("metamorph", "modumorph")
    table = unimal_table() if unimal else table_of(robots())
    net = make_network(
        name,
        "ppo_actor" if unimal else "td3_actor",
        table=table,
        obs_dim=F_UNIMAL if unimal else F_OBS,
        num_actions=A_UNIMAL if unimal else 1,
        **small(name),
    )
    layers = _layers(net)
    assert layers, name
    for layer in layers:
        d = layer.qkv.in_features
        assert torch.count_nonzero(layer.qkv.bias) == 0
        assert torch.count_nonzero(layer.proj.bias) == 0
        bound = (6.0 / (d + 3 * d)) ** 0.5  # xavier-uniform of a [3d, d] weight
        w = layer.qkv.weight
        assert w.abs().max() <= bound and w.abs().max() > 0.9 * bound
        ref = torch.nn.MultiheadAttention(d, layer.heads)
        assert ref.in_proj_weight.shape == w.shape
    if name == "modumorph":
        assert all(isinstance(m, ContextAttentionLayer) for m in layers)


def test_modumorph_context_encoders_end_with_relu_and_start_uniform():
    torch.manual_seed(0)
    table = unimal_table()
    net = make_network(
        "modumorph",
        "ppo_actor",
        table=table,
        obs_dim=F_UNIMAL,
        num_actions=A_UNIMAL,
        **small("modumorph"),
    )
    mlps = [m for m in net.modules() if isinstance(m, ContextMLP)]
    assert len(mlps) == 2  # hypernetwork context and fixed-attention context
    for m in mlps:
        assert isinstance(m.net[-1], torch.nn.ReLU)
        w = m.net[0].weight
        assert w.abs().max() <= CONTEXT_EMBED_BOUND and w.abs().max() > 0.09
        out = m(torch.randn(3, 5, w.shape[1]))
        assert (out >= 0).all()


def test_ppo_critic_loss_is_half_the_clipped_squared_error_times_value_coef(tmp_path):
    """ModuMorph / MetaMorph ppo.py: value_loss = 0.5 * max((v - R)², (v_clip - R)²).mean(),
    weighted by VALUE_COEF (ppo.critic_coeff); checked in float64 against that formula."""
    from test_ppo import tiny_recipe

    from gcnt.keys import VALUE
    from gcnt.rl.loop import prepare

    prep = prepare(tiny_recipe(tmp_path, critic_coeff=0.2, clip_value=0.2))
    learner = prep.algo.learner
    data = _ppo_batch(prep, torch.Generator().manual_seed(0))
    prep.env.close()
    loss = learner.loss.double()
    critic = learner.critic
    with torch.no_grad():
        v = critic(data.clone()).get(VALUE)
        old = data.get(VALUE)
        ret = data.get("value_target")
        v_clip = old + (v - old).clamp(-0.2, 0.2)
        hand = 0.2 * 0.5 * torch.maximum((v - ret) ** 2, (v_clip - ret) ** 2).mean()
        got = loss(data.clone())["loss_critic"]
    assert got.dtype == torch.float64
    # torchrl keeps critic_coeff as a float32 buffer (0.1 to 1.5e-8): far below the factor 2
    assert torch.allclose(got, hand, rtol=1e-6, atol=0)
    # both branches of the max occur, so the test tells ½·max from ½·unclipped
    assert ((v - ret) ** 2 < (v_clip - ret) ** 2).any() and (
        (v - ret) ** 2 > (v_clip - ret) ** 2
    ).any()


def _ppo_batch(prep, g) -> TensorDict:
    """A float64 mini-batch with the keys ClipPPOLoss reads: observations from a short rollout,
    random old values, returns and advantages far enough apart that both clip branches occur."""
    from test_ppo import rollout

    from gcnt.keys import VALUE

    data = rollout(prep, steps=6).reshape(-1)
    data = data.apply(lambda t: t.double() if t.is_floating_point() else t)
    n = data.numel()
    data.set(VALUE, torch.randn(n, 1, generator=g, dtype=torch.float64))
    data.set("value_target", 2 * torch.randn(n, 1, generator=g, dtype=torch.float64))
    data.set("advantage", torch.randn(n, 1, generator=g, dtype=torch.float64))
    return data
