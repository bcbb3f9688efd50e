"""Padding and batch-composition invariance of every method and role; no gradient to padding."""

from __future__ import annotations

import pytest
import torch
from nn_helpers import F_OBS, NAMES, ROLES, batch, place, robots, small, table_of

from gcnt.nn import graph_lookup_of, make_network

ATOL = 2e-5


def outputs(net, role: str, td) -> dict[str, torch.Tensor]:
    """The role's per-limb and per-robot outputs (PPO actor: loc, scale, log-prob of td's action)."""
    if role == "ppo_actor":
        out = net[0](td.clone())  # the parameter chain inside the ProbabilisticActor
        dist = net.get_dist(td.clone())
        return {
            "loc": out["limbs", "loc"],
            "scale": out["limbs", "scale"],
            "log_prob": dist.log_prob(td["limbs", "action"]),
        }
    out = net(td.clone())
    if role == "td3_actor":
        return {"action": out["limbs", "action"]}
    if role == "td3_critic":
        return {"limb": out["limbs", "state_action_value"], "root": out["state_action_value"]}
    return {"limb": out["limbs", "state_value"], "root": out["state_value"]}


def per_limb(key: str) -> bool:
    return key in ("action", "limb", "loc", "scale")


@pytest.mark.parametrize("role", ROLES)
@pytest.mark.parametrize("name", NAMES)
def test_padding_and_mixing_invariance(name, role):
    torch.manual_seed(0)
    rs = robots()
    big = table_of(rs, k=11)  # padded beyond the largest robot
    net = make_network(name, role, table=big, obs_dim=F_OBS, num_actions=1, **small(name))
    net.eval()
    lookup = graph_lookup_of(net)
    mixed_ids = torch.arange(len(rs)).repeat(2)
    mixed = batch(big, mixed_ids, seed=1)
    for r in (0, 3, 21, len(rs) - 1):  # walker_2, walker_7, humanoid 9 limbs, a random tree
        n = rs[r].num_limbs
        # the robot alone, padded to its own size (the MLP's input size is fixed by K: it keeps K)
        own = table_of([rs[r]], k=None if name != "mlp" else 11)
        lookup.set_table(own)
        alone = batch(own, [0, 0], seed=10 + r)
        ref = outputs(net, role, alone)
        # the same two samples inside a mixed batch of every robot (twice), padded to 11
        lookup.set_table(big)
        rows = torch.tensor([r, len(rs) + r])
        got = outputs(net, role, place(alone, mixed.clone(), rows, n))
        for key, value in ref.items():
            if per_limb(key):
                torch.testing.assert_close(got[key][rows, :n], value[:, :n], atol=ATOL, rtol=0)
                # padded limb slots of the big table carry zeros
                assert (got[key][rows, n:] == 0).all() or key == "scale"
            else:
                torch.testing.assert_close(got[key][rows], value, atol=ATOL, rtol=0)


@pytest.mark.parametrize("role", ROLES)
@pytest.mark.parametrize("name", NAMES)
def test_no_gradient_reaches_padding(name, role):
    torch.manual_seed(0)
    rs = robots()
    table = table_of(rs, k=10)
    net = make_network(name, role, table=table, obs_dim=F_OBS, num_actions=1, **small(name))
    td = batch(table, torch.arange(len(rs)), seed=2)
    obs = td["limbs", "obs"].requires_grad_()
    act = td["limbs", "action"].requires_grad_()
    outs = outputs(net, role, td)
    loss = sum((v.float() ** 2).sum() + v.float().sum() for v in outs.values())
    loss.backward()
    mask = table["limbs", "mask"][td["morph_id"]]
    amask = table["limbs", "action_mask"][td["morph_id"]]
    assert (obs.grad[~mask] == 0).all()
    assert obs.grad[mask].abs().sum() > 0
    if role == "td3_critic":
        assert (act.grad[~amask] == 0).all()  # torso and padded action slots never enter
        assert act.grad[amask].abs().sum() > 0


@pytest.mark.parametrize("name", ["gcnt", "amorpheus", "swat", "smp", "mlp"])
def test_leading_batch_dims(name):
    rs = robots()
    table = table_of(rs)
    net = make_network(name, "td3_critic", table=table, obs_dim=F_OBS, num_actions=1, **small(name))
    flat = batch(table, torch.arange(12) % len(rs), seed=4)
    nested = flat.reshape(3, 4)
    a = net(flat.clone())["state_action_value"]
    b = net(nested)["state_action_value"]
    assert b.shape == (3, 4, 1)
    torch.testing.assert_close(b.reshape(12, 1), a, atol=ATOL, rtol=0)
