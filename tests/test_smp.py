"""SMP at the original code's structure and sizes (``gcnt.nn.baselines.smp``): the parameter
count of actor and critic from the layer sizes, messages of unit length, and a TD3 critic whose Q
head reads the limb's action but not its observation."""

import torch
from nn_helpers import F_OBS, batch, double, robots, table_of

from gcnt import keys as K
from gcnt.nn import count_parameters, make_network


def lin(i, o):
    return i * o + o


def mlp_base(i, o):
    """The original's MLPBase: i → 400 → 300 → o."""
    return lin(i, 400) + lin(400, 300) + lin(300, o)


def test_parameter_counts_follow_the_original_layers():
    """Bottom-up Linear(F→64), Linear(64+32→64), Linear(64→32); top-down message MLPBase(64→32);
    actor head MLPBase(64→1); critic head MLPBase(32+1+32→1), critic input F+1."""
    table = table_of(robots())
    up = lambda f: lin(f, 64) + lin(64 + 32, 64) + lin(64, 32)  # noqa: E731
    actor = make_network("smp", "td3_actor", table=table, obs_dim=F_OBS, num_actions=1)
    critic = make_network("smp", "td3_critic", table=table, obs_dim=F_OBS, num_actions=1)
    assert count_parameters(actor) == up(F_OBS) + mlp_base(64, 32) + mlp_base(64, 1)
    assert count_parameters(critic) == up(F_OBS + 1) + mlp_base(64, 32) + mlp_base(65, 1)
    assert count_parameters(actor) == 312_101  # F = 19: 0.96 of the original's 323,781


def test_up_messages_are_unit_vectors_and_the_critic_head_sees_only_the_action():
    torch.manual_seed(0)
    table = table_of(robots())
    kw = dict(table=table, obs_dim=F_OBS, num_actions=1, msg_dim=8, hidden=12, head_hidden=(16,))
    actor = make_network("smp", "td3_actor", keep_intermediates=True, **kw).double()
    td = double(batch(table, [3, 0], seed=0))
    out = actor(td.clone())
    mask = table[K.MASK][td[K.MORPH_ID]]
    norms = out["limbs", "msg_up"].norm(dim=-1)[mask]
    assert torch.allclose(norms, torch.ones_like(norms))
    # the Q head: [up ‖ action ‖ parent's message]; an observation reaches it only through
    # the messages, so with the messages fixed the head's input changes with the action alone
    critic = make_network("smp", "td3_critic", keep_intermediates=True, **kw).double()
    head = critic["head"].module
    assert head.net[0].in_features == 2 * 8 + 1


def test_every_level_runs_when_the_deepest_cannot_be_read(monkeypatch):
    """While a CUDA graph is captured or torch.compile traces, the message passes cannot read
    the batch's deepest limb on the host; they run every level a K-limb tree can have, which
    gives the same messages (float64)."""
    from gcnt.nn.baselines import smp

    torch.manual_seed(0)
    table = table_of(robots())
    kw = dict(table=table, obs_dim=F_OBS, num_actions=1, msg_dim=8, hidden=12, head_hidden=(16,))
    actor = make_network("smp", "td3_actor", **kw).double()
    td = double(batch(table, [3, 0, 5], seed=1))
    read = actor(td.clone())[K.ACTION]
    depth = smp.tree_depth(table["graph", "parent"], table[K.MASK])
    k = table[K.MASK].shape[-1]
    assert smp.message_levels(depth, k) < k - 1  # the shortcut is real: fewer levels
    monkeypatch.setattr(torch.compiler, "is_compiling", lambda: True)
    assert smp.message_levels(depth, k) == k - 1
    assert torch.equal(actor(td.clone())[K.ACTION], read)
