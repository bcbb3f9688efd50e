"""GCNT and AMORPHEUS are equivariant to a consistent renumbering of limbs (padding included)."""

from __future__ import annotations

import pytest
import torch
from nn_helpers import F_OBS, batch, robots, small, table_of

from gcnt.nn import graph_lookup_of, make_network

PER_LIMB = [("limbs", "mask"), ("limbs", "type"), ("limbs", "action_mask"), ("graph", "traversal")]
PAIRS = [("graph", "adj"), ("graph", "dist"), ("graph", "ppr"), ("graph", "laplacian")]


def permute_table(table, perm):
    """Limb j of the new table is limb perm[j] of the old one (parents relabelled)."""
    out = table.clone()
    for key in PER_LIMB:
        out.set(key, table.get(key)[:, perm])
    for key in PAIRS:
        out.set(key, table.get(key)[:, perm][:, :, perm])
    inv = torch.argsort(perm)
    parent = table.get(("graph", "parent"))[:, perm]
    out.set(("graph", "parent"), torch.where(parent >= 0, inv[parent.clamp_min(0)], parent))
    return out


@pytest.mark.parametrize("role", ["td3_actor", "td3_critic", "ppo_critic"])
@pytest.mark.parametrize("name", ["gcnt", "amorpheus"])
def test_renumbering_limbs_permutes_outputs(name, role):
    torch.manual_seed(0)
    rs = robots()
    table = table_of(rs, k=10)
    net = make_network(name, role, table=table, obs_dim=F_OBS, num_actions=1, **small(name))
    ids = torch.tensor([3, 21, 10, len(rs) - 1, 0])
    td = batch(table, ids, seed=3)
    key = {
        "td3_actor": ("limbs", "action"),
        "td3_critic": ("limbs", "state_action_value"),
        "ppo_critic": ("limbs", "state_value"),
    }[role]
    ref = net(td.clone())
    g = torch.Generator().manual_seed(1)
    for _ in range(3):
        perm = torch.randperm(10, generator=g)  # padding slots move into the middle too
        graph_lookup_of(net).set_table(permute_table(table, perm))
        td_p = td.clone()
        td_p.set(("limbs", "obs"), td["limbs", "obs"][:, perm])
        td_p.set(("limbs", "action"), td["limbs", "action"][:, perm])
        out = net(td_p)
        torch.testing.assert_close(out[key], ref[key][:, perm], atol=2e-5, rtol=0)
        if role != "td3_actor":
            root = key[1]
            torch.testing.assert_close(out[root], ref[root], atol=2e-5, rtol=0)
        graph_lookup_of(net).set_table(table)


def test_renumbering_changes_swat_which_uses_positions():
    """Sanity check of the test itself: SWAT's traversal positions break equivariance."""
    rs = robots()
    table = table_of(rs, k=10)
    net = make_network(
        "swat", "td3_actor", table=table, obs_dim=F_OBS, num_actions=1, **small("swat")
    )
    td = batch(table, torch.tensor([3, 21]), seed=3)
    ref = net(td.clone())["limbs", "action"]
    perm = torch.tensor([0, 2, 1, 3, 4, 5, 6, 7, 8, 9])
    # permute obs/graph but keep the traversal positions attached to the slots
    permuted = permute_table(table, perm)
    permuted.set(("graph", "traversal"), table["graph", "traversal"])
    graph_lookup_of(net).set_table(permuted)
    td.set(("limbs", "obs"), td["limbs", "obs"][:, perm])
    out = net(td)["limbs", "action"]
    assert not torch.allclose(out, ref[:, perm], atol=1e-4)
