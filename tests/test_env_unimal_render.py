"""UNIMAL env: video with the tracking camera (terrain edits reach the renderer) and the
``gcnt bench-env --benchmark unimal`` command (smoke tests, few robots and steps)."""

from __future__ import annotations

import argparse
import json

import pytest
from render_helpers import gl_or_skip, no_gl

from gcnt.morphology.catalogues import resolve_robots


@pytest.mark.parametrize("world", ["mt", "obstacles"])
def test_render_terrain_world(tmp_path, world):
    imageio = pytest.importorskip("imageio.v2")
    from gcnt.envs.render import camera_id, render_rollout
    from gcnt.envs.unimal import UnimalEnv

    env = UnimalEnv(resolve_robots(["unimal_0001"]), world=world, seed=0, num_threads=1)
    assert camera_id(env.sim(0)[0], "track") >= 0
    with gl_or_skip(env):
        path = render_rollout(env, steps=6, path=tmp_path / "v.mp4", width=64, height=48)
    frames = [f for f in imageio.get_reader(str(path))]  # noqa: C416 (the reader has no len)
    assert len(frames) == 6 and frames[0].shape == (48, 64, 3)
    assert frames[-1].std() > 0


def test_render_robot_builds_a_unimal_env(tmp_path):
    pytest.importorskip("imageio.v2")
    from gcnt.envs.render import render_rollout

    try:
        path = render_rollout(
            resolve_robots(["unimal_0001"])[0],
            steps=2,
            path=tmp_path / "r.mp4",
            width=32,
            height=32,
        )
    except Exception as e:
        if no_gl(e):
            pytest.skip(f"no headless OpenGL: {e!r}")
        raise
    assert path.stat().st_size > 0


@pytest.mark.parametrize("world", ["ft", "mt"])
def test_bench_env_unimal(capsys, world):
    from gcnt.commands import bench_env

    parser = argparse.ArgumentParser()
    bench_env.add_arguments(parser)
    args = parser.parse_args(
        ["--benchmark", "unimal", "--world", world, "--robots", "unimal_0000", "unimal_0001"]
        + ["--steps", "5", "--rounds", "1", "--json", "--threads", "1"]
    )
    assert args.robots is not None
    assert bench_env.run(args) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["benchmark"] == "unimal" and result["world"] == world and result["robots"] == 2
    assert result["env_steps_per_s"] > 0 and result["raw_steps_per_s"] > 0
    share = result["hfield_share_of_env_time"]
    assert (share is None) == (world == "ft")
    if share is not None:
        assert 0 < share < 1


def test_bench_env_defaults_to_the_training_split(capsys):
    from gcnt.commands import bench_env

    parser = argparse.ArgumentParser()
    bench_env.add_arguments(parser)
    args = parser.parse_args(["--steps", "2", "--rounds", "1", "--threads", "1", "--json"])
    assert args.robots is None  # resolved from Benchmark.train_split: CWHH++'s 25 robots
    assert bench_env.run(args) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["benchmark"] == "smpenv" and result["robots"] == 25
