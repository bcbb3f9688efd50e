"""The masked PPO distribution, the ProbabilisticActor wrapper, and the TorchRL losses
(ClipPPOLoss, TD3Loss) running forward + backward on synthetic batches."""

from __future__ import annotations

import math

import pytest
import torch
from nn_helpers import (
    A_UNIMAL,
    F_OBS,
    F_UNIMAL,
    H_SMALL,
    batch,
    robots,
    small,
    table_of,
    unimal_table,
)
from reference_td3 import make_td3_critics
from tensordict.nn import InteractionType, set_interaction_type
from torchrl.modules import ProbabilisticActor
from torchrl.modules.distributions.utils import sample_and_log_prob
from torchrl.objectives import ClipPPOLoss, TD3Loss

from gcnt.nn import MaskedNormal, make_network

# ------------------------------------------------------------------------ MaskedNormal


def test_masked_log_prob_of_padded_robot_equals_unpadded():
    g = torch.Generator().manual_seed(0)
    loc, scale = torch.randn(4, 3, 2, generator=g), torch.rand(4, 3, 2, generator=g) + 0.1
    mask = torch.tensor([[True, False], [True, True], [False, False]]).expand(4, 3, 2)
    x = torch.randn(4, 3, 2, generator=g)
    # the same robot padded to 6 limbs, with garbage in the padding
    big = lambda t, fill: torch.cat([t, fill.expand(4, 3, 2)], 1)  # noqa: E731
    pl, ps = big(loc, torch.tensor(5.0)), big(scale, torch.tensor(0.01))
    pm = big(mask, torch.tensor(False))
    px = big(x, torch.tensor(-7.0))
    small_lp = MaskedNormal(loc, scale, mask).log_prob(x)
    big_lp = MaskedNormal(pl, ps, pm).log_prob(px)
    assert small_lp.shape == (4,)
    torch.testing.assert_close(small_lp, big_lp)
    want = torch.distributions.Normal(loc, scale).log_prob(x)[mask.expand(4, 3, 2)].view(4, 3)
    torch.testing.assert_close(small_lp, want.sum(-1))


def test_masked_entropy_counts_only_real_slots():
    mask = torch.tensor([[[True], [False], [True], [False]]])  # 2 real of 4
    d = MaskedNormal(torch.zeros(1, 4, 1), torch.full((1, 4, 1), 0.9), mask)
    per_slot = 0.5 + 0.5 * math.log(2 * math.pi) + math.log(0.9)
    torch.testing.assert_close(d.entropy(), torch.tensor([2 * per_slot]))


def test_sample_and_log_prob_paths_match_log_prob():
    g = torch.Generator().manual_seed(1)
    loc = torch.randn(5, 6, 2, generator=g, requires_grad=True)
    scale = torch.full((5, 6, 2), 0.9)
    mask = torch.rand(5, 6, 2, generator=g) > 0.3
    d = MaskedNormal(loc, scale, mask)
    for fn in (d.sample_and_log_prob, d.rsample_and_log_prob):
        x, lp = fn()
        assert (x[~mask] == 0).all()
        torch.testing.assert_close(lp, d.log_prob(x))
    x, lp = d.rsample_and_log_prob((3,))
    assert x.shape == (3, 5, 6, 2) and lp.shape == (3, 5)
    x.sum().backward()
    assert (loc.grad[~mask] == 0).all() and (loc.grad[mask] != 0).all()
    # torchrl's fused helper goes through the overrides
    x, lp = sample_and_log_prob(d, reparameterize=True)
    torch.testing.assert_close(lp, d.log_prob(x))
    assert torch.equal(d.deterministic_sample, torch.where(mask, loc, 0.0))


# ------------------------------------------------------------------------------- PPO


@pytest.mark.parametrize("std", ["fixed", "learned"])
def test_ppo_actor_is_a_probabilistic_actor_with_root_log_prob(std):
    table = table_of(robots())
    actor = make_network(
        "gcnt", "ppo_actor", table=table, obs_dim=F_OBS, num_actions=1, ppo_std=std, **small("gcnt")
    )
    assert isinstance(actor, ProbabilisticActor)
    td = batch(table, torch.arange(8), seed=0).exclude(("limbs", "action"))
    with set_interaction_type(InteractionType.RANDOM):
        out = actor(td.clone())
    amask = table["limbs", "action_mask"][:8]
    assert out["action_log_prob"].shape == (8,)
    assert (out["limbs", "action"][~amask] == 0).all()
    torch.testing.assert_close(
        out["action_log_prob"], actor.get_dist(td.clone()).log_prob(out["limbs", "action"])
    )
    with set_interaction_type(InteractionType.DETERMINISTIC):
        det = actor(td.clone())
    torch.testing.assert_close(det["limbs", "action"], det["limbs", "loc"])
    assert torch.allclose(out["limbs", "scale"], torch.tensor(0.9))
    assert any("log_std" in n for n, _ in actor.named_parameters()) == (std == "learned")


@pytest.mark.parametrize("name", ["gcnt", "modumorph", "metamorph"])
def test_clip_ppo_loss_forward_backward(name):
    """ClipPPOLoss on SMPENV-like robots (GCNT) and on UNIMAL-like robots with a static context
    and a height map (ModuMorph, MetaMorph: dropout is off in eval mode, so the KL is 0)."""
    torch.manual_seed(0)
    if name == "gcnt":
        table, f, a, h = table_of(robots()), F_OBS, 1, 0
    else:
        table, f, a, h = unimal_table(), F_UNIMAL, A_UNIMAL, H_SMALL
    kw = dict(table=table, obs_dim=f, num_actions=a, hfield_dim=h, **small(name))
    actor = make_network(name, "ppo_actor", ppo_std="learned", **kw).eval()
    critic = make_network(name, "ppo_critic", **kw).eval()
    n = 16
    ids = torch.arange(n) % table.batch_size[0]
    td = batch(table, ids, seed=1, f=f, hfield=h).exclude(("limbs", "action"))
    with torch.no_grad(), set_interaction_type(InteractionType.RANDOM):
        td = critic(actor(td))  # as a collector + GAE would: log-prob and old value stored
    td.set("advantage", torch.randn(n, 1))
    td.set("value_target", torch.randn(n, 1))
    loss = ClipPPOLoss(
        actor,
        critic,
        clip_epsilon=0.2,
        entropy_bonus=True,
        entropy_coeff=0.01,
        critic_coeff=0.2,
        normalize_advantage=True,
        clip_value=0.2,
    )
    assert loss.tensor_keys.action == ("limbs", "action")
    assert loss.tensor_keys.sample_log_prob == "action_log_prob"
    out = loss(td)
    # the data came from this very policy: ratio 1, KL 0
    assert abs(float(out["kl_approx"])) < 1e-5
    total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
    total.backward()
    for net in (actor, critic):
        grads = [p.grad for p in net.parameters() if p.requires_grad]
        assert all(g is not None for g in grads)
        assert sum(g.abs().sum() for g in grads) > 0


# ------------------------------------------------------------------------------- TD3


def test_td3_loss_with_twin_critics_forward_backward():
    torch.manual_seed(0)
    rs = robots()
    table = table_of(rs)
    kw = dict(table=table, obs_dim=F_OBS, num_actions=1, **small("gcnt"))
    actor = make_network("gcnt", "td3_actor", **kw)
    critics = make_td3_critics("gcnt", **kw)
    assert critics[0] is not critics[1]
    p0 = dict(critics[0].named_parameters())
    assert any(not torch.equal(p, p0[k]) for k, p in critics[1].named_parameters())
    n = 12
    ids = torch.arange(n) % len(rs)
    td = batch(table, ids, seed=0)
    nxt = batch(table, ids, seed=1).exclude(("limbs", "action"))
    nxt.update(
        {
            "reward": torch.randn(n, 1),
            "done": torch.zeros(n, 1, dtype=torch.bool),
            "terminated": torch.zeros(n, 1, dtype=torch.bool),
        }
    )
    td.set("next", nxt)
    loss = TD3Loss(actor, critics, num_qvalue_nets=2, bounds=(-1.0, 1.0), deactivate_vmap=True)
    loss.set_keys(action=("limbs", "action"))
    loss.make_value_estimator(gamma=0.99)
    out = loss(td)
    (out["loss_actor"] + out["loss_qvalue"]).backward()
    for params in (loss.actor_network_params, loss.qvalue_network_params):
        trainable = [p for p in params.values(True, True) if p.requires_grad]
        assert trainable and all(p.grad is not None for p in trainable)
        assert sum(p.grad.abs().sum() for p in trainable) > 0
    # the robot table travels as buffers, expanded once per twin critic
    assert loss.qvalue_network_params["module", "lookup", "table_limbs__mask"].shape[0] == 2


def test_critic_ignores_actions_on_torso_and_padded_slots():
    table = table_of(robots(), k=10)
    critic = make_network(
        "gcnt", "td3_critic", table=table, obs_dim=F_OBS, num_actions=1, **small("gcnt")
    )
    td = batch(table, torch.arange(10), seed=0)
    ref = critic(td.clone())
    amask = table["limbs", "action_mask"][:10]
    noisy = td.clone()
    noisy.set(("limbs", "action"), torch.where(amask, td["limbs", "action"], 123.0))
    out = critic(noisy)
    torch.testing.assert_close(out["state_action_value"], ref["state_action_value"])


def test_torchrls_td3loss_takes_gcnts_chains_as_docs_python_shows():
    """The code block of docs/python.md on torchrl's losses, run as written (its defaults: the
    critic vmapped as a twin ensemble), then a backward that reaches every network."""
    import re
    from pathlib import Path

    doc = (Path(__file__).parents[1] / "docs/python.md").read_text()
    (block,) = [b for b in re.findall(r"```python\n(.*?)```", doc, re.S) if "TD3Loss" in b]
    scope: dict = {}
    exec(compile(block, "docs/python.md", "exec"), scope)
    out = scope["losses"]
    (out["loss_actor"] + out["loss_qvalue"]).backward()
    loss = scope["loss"]
    for params in (loss.actor_network_params, loss.qvalue_network_params):
        grads = [p.grad for p in params.values(True, True) if p.requires_grad]
        assert grads and any(g is not None and g.abs().sum() > 0 for g in grads)


def test_torchrls_clip_ppo_loss_takes_gcnts_chains_as_docs_python_shows():
    """docs/python.md's ClipPPOLoss block, run as written (its defaults), then a backward that
    reaches both networks; the data came from this very policy, so the ratio is 1."""
    import re
    from pathlib import Path

    doc = (Path(__file__).parents[1] / "docs/python.md").read_text()
    (block,) = [b for b in re.findall(r"```python\n(.*?)```", doc, re.S) if "ClipPPOLoss" in b]
    scope: dict = {}
    exec(compile(block, "docs/python.md", "exec"), scope)
    out = scope["losses"]
    assert abs(float(out["kl_approx"])) < 1e-5
    (out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]).backward()
    for net in (scope["actor"], scope["critic"]):
        grads = [p.grad for p in net.parameters() if p.requires_grad]
        assert grads and any(g is not None and g.abs().sum() > 0 for g in grads)
