"""Initial weights as the original code sets them (``gcnt.nn.init``), and what they lead to: every
UNIMAL method starts with action means and values of the baselines' size (not a saturated
bang-bang policy), checked on real training robots at the paper's sizes."""

import pytest
import torch
from nn_helpers import F_OBS, robots, table_of

from gcnt.analysis.init_spread import METHODS, initial_spread
from gcnt.nn import make_network
from gcnt.nn.layers import last_linear


def _stage(net, name):
    return net[name].module


@pytest.mark.parametrize(
    ("preset", "decoder_bound"), [("smpenv", 0.1), ("unimal", 0.01)], ids=["smpenv", "unimal"]
)
def test_gcnt_embedding_fusion_and_decoder_start_as_the_original_code(preset, decoder_bound):
    torch.manual_seed(0)
    table = table_of(robots())
    net = make_network(
        "gcnt", "td3_actor", table=table, obs_dim=F_OBS, num_actions=1, preset=preset
    )
    for stage in ("encoder", "fusion"):
        w = last_linear(_stage(net, stage)).weight
        assert w.abs().max() <= 0.1 and w.abs().max() > 0.09  # U(±0.1), drawn
    out = last_linear(_stage(net, "head"))
    assert out.weight.abs().max() <= decoder_bound
    assert torch.count_nonzero(out.bias) == 0
    # init="torch" keeps PyTorch's defaults (the decoder's bias is drawn, not zero)
    plain = make_network(
        "gcnt", "td3_actor", table=table, obs_dim=F_OBS, num_actions=1, preset=preset, init="torch"
    )
    assert torch.count_nonzero(last_linear(_stage(plain, "head")).bias) > 0


def test_an_unknown_init_scheme_is_named():
    with pytest.raises(ValueError, match="init scheme 'xavier'"):
        make_network(
            "amorpheus",
            "td3_actor",
            table=table_of(robots()),
            obs_dim=F_OBS,
            num_actions=1,
            init="xavier",
        )


@pytest.mark.slow
def test_every_unimal_method_starts_within_the_baselines_range():
    """Initial action-mean and value spread on unit-normal observations of 4 training robots: the
    largest method is at most twice the largest baseline (MetaMorph, MetaMorph*, ModuMorph),
    and no method's action means reach the action bound."""
    rows = initial_spread("unimal", seeds=(0,), num_robots=4, samples=4)
    by = {r["method"]: r for r in rows}
    assert set(by) == set(METHODS["unimal"])
    baselines = [by[m] for m in ("metamorph", "metamorph_star", "modumorph")]
    top_action = max(r["action_std"] for r in baselines)
    top_value = max(r["value_std"] for r in baselines)
    for m in ("gcnt", "gcnt_hn"):
        assert by[m]["action_std"] <= 2 * top_action, (m, by[m], top_action)
        assert by[m]["value_std"] <= 2 * top_value, (m, by[m], top_value)
    assert all(r["action_std"] < 1.0 for r in rows)
