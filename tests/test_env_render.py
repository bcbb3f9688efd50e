"""Rendering a rollout to mp4, and the ``gcnt bench-env`` command (smoke tests)."""

from __future__ import annotations

import json

import pytest

from gcnt.morphology.catalogues import smpenv_robot


def test_render_rollout_writes_mp4(tmp_path):
    imageio = pytest.importorskip("imageio.v2")
    from gcnt.envs.render import render_rollout

    try:
        path = render_rollout(
            smpenv_robot("walker_7_main"), steps=12, path=tmp_path / "v.mp4", width=64, height=48
        )
    except Exception as e:  # no EGL on this machine
        if "EGL" in repr(e) or "OpenGL" in repr(e) or "gl" in type(e).__name__.lower():
            pytest.skip(f"no headless OpenGL: {e!r}")
        raise
    frames = [f for f in imageio.get_reader(str(path))]  # noqa: C416 (the reader has no len)
    assert len(frames) == 4  # 125 Hz control rate, subsampled to <= 60 fps: every 3rd step
    assert frames[0].shape == (48, 64, 3)
    assert frames[-1].std() > 0  # not a blank image


def test_render_camera_fallback():
    from gcnt.envs.render import camera_id

    m = smpenv_robot("cheetah_2_back").compile()
    assert camera_id(m, "no_such_camera") == -1
    assert camera_id(m, -1) == -1


def test_bench_env_command(capsys):
    import argparse

    from gcnt.cli import COMMANDS
    from gcnt.commands import bench_env

    assert COMMANDS["bench-env"][0] == "gcnt.commands.bench_env"
    parser = argparse.ArgumentParser()
    bench_env.add_arguments(parser)
    args = parser.parse_args(
        ["--benchmark", "smpenv", "--robots", "walker_2_main", "cheetah_3_back", "--steps", "20"]
        + ["--rounds", "1", "--json"]
    )
    assert bench_env.run(args) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["robots"] == 2 and result["benchmark"] == "smpenv"
    assert result["env_steps_per_s"] > 0 and result["raw_steps_per_s"] > 0
    ratio = result["env_steps_per_s"] / result["raw_steps_per_s"]
    assert result["ratio"] == pytest.approx(ratio, rel=1e-2)


def test_bench_env_unknown_benchmark():
    import argparse

    from gcnt.commands import bench_env

    parser = argparse.ArgumentParser()
    bench_env.add_arguments(parser)
    args = parser.parse_args(["--benchmark", "smpenvv", "--robots", "walker_2_main"])
    with pytest.raises(ValueError, match="did you mean 'smpenv'"):
        bench_env.run(args)
