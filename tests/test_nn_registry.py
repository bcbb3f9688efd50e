"""The network registry: names, roles, presets, overrides, errors; the params command."""

from __future__ import annotations

import argparse

import pytest
import torch
from nn_helpers import F_OBS, batch, robots, small, table_of
from tensordict.nn import TensorDictSequential

from gcnt.nn import GCNTConfig, GraphLookup, count_parameters, make_config, make_network


@pytest.fixture(scope="module")
def table():
    return table_of(robots())


def test_presets_are_the_paper_sizes():
    s, u = GCNTConfig.preset("smpenv"), GCNTConfig.preset("unimal")
    assert (s.d_model, s.layers, s.heads, s.ff, s.gcn_width, s.gcn_layers) == (
        128,
        3,
        2,
        256,
        16,
        4,
    )
    assert (u.d_model, u.layers, u.heads, u.ff, u.gcn_width, u.gcn_layers) == (
        128,
        5,
        2,
        1024,
        23,
        4,
    )
    assert GCNTConfig.preset("smpenv", layers=1, d_model=32).layers == 1
    a = make_config("amorpheus")
    assert (a.d_model, a.layers, a.heads, a.ff, a.dropout, a.norm_first) == (
        128,
        3,
        2,
        256,
        0.0,
        False,
    )
    assert make_config("gcnt_no_wl").use_wl is False


def test_chains_start_with_graph_lookup_and_read_only_env_keys(table):
    for name in ("gcnt", "amorpheus", "swat", "smp", "mlp"):
        critic = make_network(
            name, "td3_critic", table=table, obs_dim=F_OBS, num_actions=1, **small(name)
        )
        assert isinstance(critic, TensorDictSequential)
        assert isinstance(critic["lookup"], GraphLookup) and critic[0] is critic["lookup"]
        assert set(critic.in_keys) == {"morph_id", ("limbs", "obs"), ("limbs", "action")}
        actor = make_network(
            name, "td3_actor", table=table, obs_dim=F_OBS, num_actions=1, **small(name)
        )
        assert set(actor.in_keys) == {"morph_id", ("limbs", "obs")}


def test_network_from_a_list_of_robots_equals_one_from_its_table(table):
    torch.manual_seed(0)
    a = make_network(
        "gcnt", "td3_actor", table=list(robots()), obs_dim=F_OBS, num_actions=1, **small("gcnt")
    )
    b = make_network(
        "gcnt", "td3_actor", table=table, obs_dim=F_OBS, num_actions=1, **small("gcnt")
    )
    b.load_state_dict(a.state_dict())
    td = batch(table, torch.arange(5), seed=0)
    torch.testing.assert_close(a(td.clone())["limbs", "action"], b(td.clone())["limbs", "action"])
    assert a["lookup"].robot_names[0] == robots()[0].name


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"name": "gcnn"}, r"unknown network 'gcnn'.*did you mean 'gcnt'"),
        ({"name": "amorpheous"}, r"did you mean 'amorpheus'"),
        ({"role": "td3_actr"}, r"unknown role 'td3_actr'.*did you mean 'td3_actor'"),
        ({"layer": 2}, r"unknown GCNTConfig field 'layer'.*did you mean 'layers'"),
        ({"use_gnc": False}, r"'use_gnc'.*did you mean 'use_gcn'"),
        ({"preset": "unimall"}, r"unknown preset 'unimall'.*did you mean 'unimal'"),
        ({"name": "gcnt_no_gcn", "use_gcn": True}, r"gcnt_no_gcn.*fixes use_gcn=False"),
        ({"name": "amorpheus", "gcn_width": 4}, r"unknown AmorpheusConfig field 'gcn_width'"),
        ({"heads": 3}, r"not divisible by heads"),
        ({"ppo_std": "adaptive"}, r"ppo_std must be"),
        ({"name": "swat", "traversal_widths": (10, 10, 10)}, r"summing to d_model"),
    ],
)
def test_registry_errors_name_the_culprit(table, kwargs, match):
    args = {"name": "gcnt", "role": "td3_actor", **kwargs}
    name, role = args.pop("name"), args.pop("role")
    with pytest.raises(ValueError, match=match):
        make_network(name, role, table=table, obs_dim=F_OBS, num_actions=1, **args)


def test_params_command_prints_every_method(capsys):
    from gcnt.analysis import params as counts
    from gcnt.commands import params

    params.run(argparse.Namespace(benchmark="smpenv"))
    out = capsys.readouterr().out
    for name in counts.METHODS["smpenv"]:
        assert name in out
    rows = {r["method"]: r for r in counts.count_table("smpenv")}
    # GCNT's extra modules add a few percent to the Transformer (paper: about 2%)
    assert 1.0 < rows["gcnt"]["actor"] / rows["amorpheus"]["actor"] < 1.05
    # AMORPHEUS at its published sizes (about 400k for the public actor)
    assert rows["amorpheus"]["actor"] == 400_404


def test_count_excludes_the_robot_table(table):
    a = make_network("gcnt", "td3_actor", table=table, obs_dim=F_OBS, num_actions=1)
    b = make_network(
        "gcnt", "td3_actor", table=table_of(robots()[:2], k=9), obs_dim=F_OBS, num_actions=1
    )
    assert count_parameters(a) == count_parameters(b)
