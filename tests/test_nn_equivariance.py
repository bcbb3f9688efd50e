"""GCNT, AMORPHEUS, MetaMorph*, ModuMorph and GCNT+HN are equivariant to a consistent renumbering
of limbs (padding included); SWAT's traversal positions and MetaMorph's position embedding are
not. In float64: the property is structural."""

from __future__ import annotations

import pytest
import torch
from nn_helpers import (
    A_UNIMAL,
    F_OBS,
    F_UNIMAL,
    H_SMALL,
    batch,
    double,
    robots,
    small,
    table_of,
    unimal_table,
)

from gcnt.nn import graph_lookup_of, make_network

PER_LIMB = [
    ("limbs", "mask"),
    ("limbs", "type"),
    ("limbs", "action_mask"),
    ("limbs", "context"),
    ("graph", "traversal"),
]
PAIRS = [("graph", "adj"), ("graph", "dist"), ("graph", "ppr"), ("graph", "laplacian")]
ATOL = 1e-10


def permute_table(table, perm):
    """Limb j of the new table is limb perm[j] of the old one (parents relabelled)."""
    out = table.clone()
    for key in PER_LIMB:
        if key in table.keys(True):
            out.set(key, table.get(key)[:, perm])
    for key in PAIRS:
        out.set(key, table.get(key)[:, perm][:, :, perm])
    inv = torch.argsort(perm)
    parent = table.get(("graph", "parent"))[:, perm]
    out.set(("graph", "parent"), torch.where(parent >= 0, inv[parent.clamp_min(0)], parent))
    return out


OUT_KEY = {
    "td3_actor": ("limbs", "action"),
    "td3_critic": ("limbs", "state_action_value"),
    "ppo_critic": ("limbs", "state_value"),
    "ppo_actor": ("limbs", "loc"),
}


def setting(name: str):
    """(table padded to 10-12, widths, ids) of the setting a method is tested in."""
    if name in ("gcnt", "amorpheus"):
        rs = robots()
        return table_of(rs, k=10), F_OBS, 1, 0, torch.tensor([3, 21, 10, len(rs) - 1, 0])
    return unimal_table(k=12), F_UNIMAL, A_UNIMAL, H_SMALL, torch.tensor([0, 4, 2, 1, 5])


def check_equivariance(name: str, role: str, *, expect: bool = True, **kw) -> None:
    torch.manual_seed(0)
    table, f, a, h, ids = setting(name)
    k = table["limbs", "mask"].shape[-1]
    net = make_network(
        name,
        role,
        table=table,
        obs_dim=f,
        num_actions=a,
        hfield_dim=h,
        keep_intermediates=True,
        **{**small(name), **kw},
    ).double()
    net.eval()
    chain = net[0] if role == "ppo_actor" else net
    td = double(batch(table, ids, seed=3, f=f, hfield=h))
    key = OUT_KEY[role]
    ref = chain(td.clone())
    g = torch.Generator().manual_seed(1)
    broken = False
    for _ in range(3):
        perm = torch.randperm(k, generator=g)  # padding slots move into the middle too
        graph_lookup_of(net).set_table(permute_table(table, perm))
        td_p = td.clone()
        td_p.set(("limbs", "obs"), td["limbs", "obs"][:, perm])
        td_p.set(("limbs", "action"), td["limbs", "action"][:, perm])
        out = chain(td_p)
        graph_lookup_of(net).set_table(table)
        if not expect:
            broken |= not torch.allclose(out[key], ref[key][:, perm], atol=1e-6)
            continue
        torch.testing.assert_close(out[key], ref[key][:, perm], atol=ATOL, rtol=0)
        if role in ("td3_critic", "ppo_critic"):
            root = key[1]
            torch.testing.assert_close(out[root], ref[root], atol=ATOL, rtol=0)
    if not expect:
        assert broken, f"{name} was expected to depend on limb numbering"


@pytest.mark.parametrize("role", ["td3_actor", "td3_critic", "ppo_critic"])
@pytest.mark.parametrize("name", ["gcnt", "amorpheus"])
def test_renumbering_limbs_permutes_outputs_smpenv(name, role):
    check_equivariance(name, role)


@pytest.mark.parametrize("role", ["ppo_actor", "ppo_critic", "td3_critic"])
@pytest.mark.parametrize("name", ["metamorph_star", "modumorph", "gcnt_hn"])
def test_renumbering_limbs_permutes_outputs_unimal(name, role):
    check_equivariance(name, role)


def test_renumbering_changes_metamorph_which_embeds_positions():
    """MetaMorph's learned position embedding (by slot) breaks equivariance: the check above
    can fail."""
    check_equivariance("metamorph", "ppo_actor", expect=False)


def test_renumbering_changes_swat_which_uses_positions():
    """Sanity check of the test itself: SWAT's traversal positions break equivariance."""
    rs = robots()
    table = table_of(rs, k=10)
    net = make_network(
        "swat", "td3_actor", table=table, obs_dim=F_OBS, num_actions=1, **small("swat")
    ).double()
    td = double(batch(table, torch.tensor([3, 21]), seed=3))
    ref = net(td.clone())["limbs", "action"]
    perm = torch.tensor([0, 2, 1, 3, 4, 5, 6, 7, 8, 9])
    # permute obs/graph but keep the traversal positions attached to the slots
    permuted = permute_table(table, perm)
    permuted.set(("graph", "traversal"), table["graph", "traversal"])
    graph_lookup_of(net).set_table(permuted)
    td.set(("limbs", "obs"), td["limbs", "obs"][:, perm])
    out = net(td)["limbs", "action"]
    assert not torch.allclose(out, ref[:, perm], atol=1e-6)
