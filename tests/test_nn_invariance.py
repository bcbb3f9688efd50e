"""Padding and batch-composition invariance of every method and role; no gradient to padded limbs
or masked action slots. SMPENV-like and UNIMAL-like settings (the latter with a static limb
context and a height map). All in float64: the properties are structural, so they must hold to
float64 precision whatever the CPU's float32 rounding."""

from __future__ import annotations

import pytest
import torch
from nn_helpers import (
    A_UNIMAL,
    F_OBS,
    F_UNIMAL,
    H_SMALL,
    NAMES,
    ROLES,
    UNIMAL_NAMES,
    batch,
    double,
    place,
    robots,
    small,
    table_of,
    unimal_robots,
    unimal_table,
)

from gcnt.nn import graph_lookup_of, make_network

ATOL = 1e-10


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


class Setting:
    """Robots, widths and table builder of one benchmark-like setting."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        if kind == "smpenv":
            self.rs, self.f, self.a, self.h = robots(), F_OBS, 1, 0
            self.table = lambda rs, k=None: table_of(rs, k)
            self.probe = (0, 3, 21, len(self.rs) - 1)  # walker_2, walker_7, humanoid, random
        else:
            self.rs, self.f, self.a, self.h = unimal_robots(), F_UNIMAL, A_UNIMAL, H_SMALL
            self.table = lambda rs, k=None: unimal_table(k, rs)
            self.probe = (0, 1, 3)  # 11 limbs, 4 limbs, 2 limbs

    def net(self, name: str, role: str, table, **kw):
        net = make_network(
            name,
            role,
            table=table,
            obs_dim=self.f,
            num_actions=self.a,
            hfield_dim=self.h,
            **{**small(name), **kw},
        )
        return net.double()

    def batch(self, table, ids, seed):
        return double(batch(table, ids, seed=seed, f=self.f, hfield=self.h))


CASES = [("smpenv", n) for n in NAMES] + [("unimal", n) for n in UNIMAL_NAMES]


@pytest.mark.parametrize("role", ROLES)
@pytest.mark.parametrize(("kind", "name"), CASES)
def test_padding_and_mixing_invariance(kind, name, role):
    torch.manual_seed(0)
    s = Setting(kind)
    rs, pad = s.rs, 12
    big = s.table(rs, pad)  # padded beyond the largest robot
    net = s.net(name, role, big)
    net.eval()
    lookup = graph_lookup_of(net)
    mixed_ids = torch.arange(len(rs)).repeat(2)
    mixed = s.batch(big, mixed_ids, seed=1)
    flat = name in ("mlp", "sr")  # a flat MLP's input size is fixed by K: it keeps K
    for r in s.probe:
        n = rs[r].num_limbs
        # the robot alone, padded to its own size
        own = s.table([rs[r]], pad if flat else None)
        lookup.set_table(own)
        alone = s.batch(own, [0, 0], seed=10 + r)
        ref = outputs(net, role, alone)
        # the same two samples inside a mixed batch of every robot (twice), padded to 12
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
@pytest.mark.parametrize(("kind", "name"), CASES)
def test_no_gradient_reaches_padding_or_masked_action_slots(kind, name, role):
    torch.manual_seed(0)
    s = Setting(kind)
    table = s.table(s.rs, 12)
    net = s.net(name, role, table)
    td = s.batch(table, torch.arange(len(s.rs)), seed=2)
    obs = td["limbs", "obs"].requires_grad_()
    act = td["limbs", "action"].requires_grad_()
    outs = outputs(net, role, td)
    loss = sum((v**2).sum() + v.sum() for v in outs.values())
    loss.backward()
    mask = table["limbs", "mask"][td["morph_id"]]
    amask = table["limbs", "action_mask"][td["morph_id"]]
    assert (obs.grad[~mask] == 0).all()
    assert obs.grad[mask].abs().sum() > 0
    if role == "td3_critic":
        assert (act.grad[~amask] == 0).all()  # torso, padded and missing-joint slots never enter
        assert act.grad[amask].abs().sum() > 0
    if role == "ppo_actor":
        assert act.grad is not None and (act.grad[~amask] == 0).all()  # log-prob ignores them


@pytest.mark.parametrize(
    ("kind", "name"),
    [("smpenv", n) for n in ("gcnt", "amorpheus", "swat", "smp", "mlp")]
    + [("unimal", n) for n in ("metamorph", "modumorph", "gcnt_hn")],
)
def test_leading_batch_dims(kind, name):
    s = Setting(kind)
    table = s.table(s.rs)
    net = s.net(name, "td3_critic", table)
    net.eval()
    flat = s.batch(table, torch.arange(12) % len(s.rs), seed=4)
    nested = flat.reshape(3, 4)
    a = net(flat.clone())["state_action_value"]
    b = net(nested)["state_action_value"]
    assert b.shape == (3, 4, 1)
    torch.testing.assert_close(b.reshape(12, 1), a, atol=ATOL, rtol=0)
