"""``gcnt bench-train``'s end-to-end window and report (the arithmetic: test_bench_arithmetic)."""

from __future__ import annotations

import logging

import pytest

from gcnt.bench.td3 import end_to_end_rate
from gcnt.cli import main as gcnt
from gcnt.recipes import load_recipe


def test_end_to_end_counts_the_updates_of_the_timed_steps_only(recipe_file):
    # one robot, mixed schedule, one update per env step: every timed batch of 5 steps is
    # followed by 5 updates. A warm-up that is not a whole number of batches (22: training
    # rounds it to 25) must not add the updates of the batch that ends the random phase.
    recipe = load_recipe(recipe_file, ["td3.schedule=mixed", "td3.updates_per_step=1"])
    out = end_to_end_rate(recipe, warmup=22, steps=30)
    assert out["env_steps"] >= 25 and out["env_steps"] % 5 == 0
    assert out["updates"] == out["env_steps"]
    assert out["updates_per_s"] == out["env_steps_per_s"]


@pytest.mark.slow
def test_the_report_is_not_mixed_with_training_log_lines(recipe_file, caplog, capsys):
    caplog.set_level(logging.INFO)
    argv = ["bench-train", str(recipe_file), "--updates", "2", "--steps", "10", "--warmup", "8"]
    assert gcnt(argv) == 0
    assert not [r for r in caplog.records if r.levelno < logging.WARNING]
    out = capsys.readouterr().out
    assert "ratio to the bare update" in out and "share of the time spent in updates" in out
    # operators of each step, new and previous, and the previous update's time in one run
    assert out.count("operators: critic step") == 2 and out.count("new ÷ previous") == 2
    # the level is restored afterwards: other commands in the process log as before
    assert logging.getLogger("gcnt").level <= logging.INFO


@pytest.mark.slow
def test_the_profiler_lines_stay_out_of_the_report():
    """torch's profiler writes ``USDT: ... profiler_start`` lines to file descriptor 2 whenever
    ``count_launches`` profiles; they are left out, anything else written there is kept."""
    import subprocess
    import sys

    code = (
        "import os, torch\n"
        "from gcnt.bench.common import count_launches\n"
        "def fn():\n"
        "    os.write(2, b'a line of the update\\n')\n"
        "    return torch.ones(3) + 1\n"
        "print(count_launches(fn))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert int(done.stdout) >= 1
    assert done.stderr == "a line of the update\n"


def test_the_ensemble_update_dispatches_fewer_operators_than_two_critics(recipe_file):
    """The critic step of the ensemble in one call dispatches well under the two critics'
    operators. With its members on two threads, the update also splits the batch in halves
    between the threads for the target actor (a few more operators in the critic step) and the
    actor step (two actor passes, each on half the batch: about twice the operators)."""
    from gcnt.bench.td3 import bare_update_rate

    recipe = load_recipe(recipe_file, ["td3.schedule=mixed", "compile.twin_threads=true"])
    out = bare_update_rate(recipe, n_updates=2, rounds=1)
    new, old = out["new"]["operators"], out["previous"]["operators"]
    one = out["one_call"]["operators"]
    assert out["twin_threads"]
    assert one["critic_step"] < 0.75 * old["critic_step"]
    assert one["per_update"] < old["per_update"]
    assert new["critic_step"] <= 1.1 * old["critic_step"]
    assert new["actor_step"] <= 2.2 * old["actor_step"]
    assert one["working_per_update"] < 0.8 * old["working_per_update"]
    assert 0 < new["working_per_update"] < new["per_update"]
    assert out["ratio_to_previous"] > 0 and out["one_call"]["update_ms"] > 0


def test_working_operators_leave_out_views_but_not_copies():
    """count_operators: a view or a same-dtype ``to`` dispatches without writing data; a
    reshape that has to copy, a cast and arithmetic write data."""
    import torch

    from gcnt.bench.common import count_operators

    x = torch.ones(4, 6)
    assert count_operators(lambda: x.view(6, 4).t().unsqueeze(0).to(torch.float32)) == (4, 0)
    assert count_operators(lambda: x.t().reshape(24)) == (2, 1)  # strided: reshape copies
    assert count_operators(lambda: x.to(torch.float64) + 1) == (2, 2)


def test_the_paper_schedule_window_is_whole_rounds():
    """Under the paper schedule the timed window runs from the end of one update phase to the
    end of a later one: the steps collected before the first phase ended and after the last are
    left out, so that steps and updates are those of whole rounds."""
    from gcnt.bench.td3 import _whole_rounds

    def row(steps, updates):
        return {"env_steps": steps, "updates": updates, "env_steps_per_s": 10.0}

    start = row(100, 0)
    rows = [row(110, 0), row(120, 20), row(130, 20), row(140, 40), row(150, 40), row(160, 60)]
    first, window, rounds = _whole_rounds(start, rows + [row(170, 60)], "paper")
    assert first["env_steps"] == 120 and window[-1]["env_steps"] == 160 and rounds == 2
    assert window[-1]["updates"] - first["updates"] == 40
    assert _whole_rounds(start, rows[:3], "paper") == (start, [], 0)  # one phase: no round
    assert _whole_rounds(start, rows, "mixed") == (start, rows, 3)  # every batch counts


def test_matrix_products_of_a_linear_layer_and_their_flops():
    """The products a linear layer's forward and backward dispatch, with their shapes; their
    FLOPs are what torch's counter finds."""
    import torch

    from gcnt.bench.common import count_flops, matrix_products, product_flops

    layer = torch.nn.Linear(6, 4)
    x = torch.randn(5, 6)
    products, (flops, _) = matrix_products(lambda: count_flops(lambda: layer(x).sum().backward()))
    assert ("addmm", (5, 6), (6, 4)) in products
    assert (
        sum(n * product_flops(*key) for key, n in products.items()) == flops == 2 * 2 * 5 * 6 * 4
    )  # forward, weight gradient
    batched, _ = matrix_products(lambda: torch.bmm(torch.ones(3, 2, 5), torch.ones(3, 5, 7)))
    assert batched == {("bmm", (3, 2, 5), (3, 5, 7)): 1}
    assert product_flops("bmm", (3, 2, 5), (3, 5, 7)) == 2 * 3 * 2 * 5 * 7


@pytest.mark.slow
def test_the_compiled_line_and_the_shapes_peak(recipe_file, capsys, monkeypatch):
    """``--compiled`` adds compiled ÷ eager for the bare update and the compile time (torch.compile
    left out here: the line's making, not inductor, is under test); every schedule reports the
    matmul rate at the update's own shapes."""
    import torch

    monkeypatch.setattr(torch, "compile", lambda fn, **kw: fn)
    argv = ["bench-train", str(recipe_file), "--updates", "2", "--steps", "10", "--warmup", "8"]
    assert gcnt([*argv, "--compiled"]) == 0
    out = capsys.readouterr().out
    assert out.count("compiled ÷ eager bare update") == 2 and out.count("compile time") == 2
    assert out.count("matmul rate at the update's own product shapes") == 2


@pytest.mark.parametrize("threads", ["true", "false"])
def test_the_update_by_part(recipe_file, capsys, threads):
    """``--parts``: every part of the update in ms, with the in-turn column where the twin
    critics run on two threads; the learner's methods and the module's functions are restored."""
    import json

    from gcnt.rl.td3 import learner as module

    before = (module.apply_gradients, module.soft_update)
    argv = ["bench-train", str(recipe_file), f"compile.twin_threads={threads}", "--parts"]
    assert gcnt([*argv, "--updates", "2", "--rounds", "2", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert (module.apply_gradients, module.soft_update) == before
    assert ("in_turn" in out) == (threads == "true")
    for column in [c for c in ("in_turn", "as_run") if c in out]:
        # the actor's halves run only where the critics run on two threads
        assert (out[column]["actor"] is None) == (threads == "false")
        parts = {k: v or 0.0 for k, v in out[column].items()}
        assert parts["update"] > 0 and parts["critic_step"] > 0 and parts["actor_step"] > 0
        # the parts of a step lie inside it, and both steps inside the update
        inside = parts["target_actor"] + parts["target_critics"] + parts["critics"]
        assert inside + parts["critic_tail"] <= parts["critic_step"]
        assert parts["actor_tail"] + parts["soft_update"] <= parts["actor_step"]
        assert parts["critic_step"] + parts["actor_step"] <= parts["update"]
    assert gcnt([*argv, "--updates", "2", "--rounds", "1"]) == 0
    text = capsys.readouterr().out
    assert "target critics" in text and "whole update" in text
    assert ("actor loss and gradients" in text) == (threads == "true")
    assert ("->" in text) == (threads == "true")


@pytest.mark.slow
def test_the_update_in_two_processes(recipe_file, capsys):
    """``--processes``: the update alone and in two processes at once (the second one spawned
    with the same recipe), each process's time and the throughput of both over one."""
    import json

    argv = ["bench-train", str(recipe_file), "--processes", "--updates", "2", "--rounds", "1"]
    assert gcnt([*argv, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    t, o = out["together_ms"]
    assert out["alone_ms"] > 0 and t > 0 and o > 0
    assert out["throughput_ratio"] == pytest.approx(out["alone_ms"] * (1 / t + 1 / o))


@pytest.mark.parametrize(
    "recipe, options, says",
    [
        ("unimal/quickstart", ["--parts"], "--parts measures TD3 recipes"),
        ("unimal/quickstart", ["--compiled"], "--compiled measures TD3 recipes"),
        ("quickstart", ["--workers", "1,2"], "--workers measures PPO recipes"),
        ("quickstart", ["--parts", "--processes"], "--parts and --processes each measure"),
        ("quickstart", ["--stacked-seeds", "2", "--against", "td3.tau=0.01"], "--against adds"),
    ],
)
def test_options_a_measurement_would_ignore_are_refused_in_one_line(recipe, options, says, capsys):
    """Before: a PPO recipe with --parts ran PPO's report, and --compiled beside --parts was
    dropped, without a word."""
    assert gcnt(["bench-train", recipe, *options]) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and len(err.splitlines()) == 1
