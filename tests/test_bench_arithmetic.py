"""``gcnt bench-train``'s arithmetic figures: FLOPs counted from the shapes, share of a peak."""

import math

import torch
import torch.nn.functional as F

from gcnt.bench.common import arithmetic, count_flops, matmul_peak_gflops


def test_count_flops_of_a_linear_layer_and_its_backward():
    lin = torch.nn.Linear(32, 96)
    x = torch.randn(1920, 32)
    flops, out = count_flops(lambda: lin(x))
    assert flops == 2 * 1920 * 32 * 96
    assert out.shape == (1920, 96)
    flops, _ = count_flops(lambda: lin(x).sum().backward())
    assert flops == 2 * (2 * 1920 * 32 * 96)  # forward, and the weight's gradient


def test_count_flops_counts_the_cpu_attention_kernel():
    n, h, k, d = 8, 2, 5, 16
    q = torch.randn(n, h, k, d)
    with torch.no_grad():
        flops, _ = count_flops(lambda: F.scaled_dot_product_attention(q, q, q))
    assert flops == 2 * (2 * n * h * k * k * d)  # scores and weighted sum


def test_arithmetic_share_of_the_peak():
    a = arithmetic(5e8, 40.0, peak=100.0)
    assert math.isclose(a["gflops_per_s"], 20.0)
    assert math.isclose(a["share_of_peak"], 0.2)
    assert matmul_peak_gflops(size=64, repeats=2) > 0


def test_count_launches_counts_the_top_level_operators_on_a_cpu():
    from gcnt.bench.common import count_launches, launch_line

    x = torch.randn(8, 8)
    # three operators called by the caller; mm's own internals are not counted again
    assert count_launches(lambda: (x @ x).relu().sum()) == 3
    lin = torch.nn.Linear(8, 4)
    one = count_launches(lambda: lin(x))
    assert count_launches(lambda: [lin(x) for _ in range(5)]) == 5 * one
    assert "dispatched operators per update: 2.0 us per launch" in launch_line(1000, 2.0, "cpu")


def test_flops_of_an_update_with_critics_on_two_threads_count_both_critics():
    """The FLOP counter sees its own thread only: counted on one thread
    (``on_this_thread``), an update whose twin critics run on two threads counts what the
    one-call ensemble counts; counted as it runs, the helper thread's critic is missing."""
    from pathlib import Path

    from gcnt.bench.td3 import on_this_thread
    from gcnt.recipes import load_recipe
    from gcnt.rl.factories import make_env, train_robots
    from gcnt.rl.td3 import replay as rb
    from gcnt.rl.td3.learner import TD3Learner

    quick = Path(__file__).parents[1] / "recipes/quickstart.yaml"
    recipe = load_recipe(quick, ["network.kwargs={d_model: 8, layers: 1, ff: 8, heads: 2}"])
    env = make_env(recipe, train_robots(recipe))
    replay = rb.RobotReplay(3, capacity=10, batch_size=4)
    replay.extend(env.rollout(5, break_when_any_done=False))
    batch = replay.sample_mixed()
    threads = TD3Learner(recipe, env, twin_threads=True)
    one_call = TD3Learner(recipe, env, twin_threads=False)
    env.close()
    with on_this_thread(threads):
        counted, _ = count_flops(lambda: threads.critic_step(batch))
    as_run, _ = count_flops(lambda: threads.critic_step(batch))
    whole, _ = count_flops(lambda: one_call.critic_step(batch))
    # the same products as one call, and the robot-only stages of the target actor once more
    # (each thread computes them for its half of the batch)
    assert whole <= counted <= 1.05 * whole and counted > as_run
