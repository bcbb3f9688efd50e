"""Rendering a rollout to mp4, and the ``gcnt bench-env`` command (smoke tests)."""

from __future__ import annotations

import json

import pytest
from render_helpers import gl_or_skip, no_gl

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
    # both rates are rounded to 0.1 and the ratio to 0.001
    assert result["ratio"] == pytest.approx(ratio, rel=1e-2, abs=1e-3)


def test_bench_env_unknown_benchmark():
    import argparse

    from gcnt.commands import bench_env

    parser = argparse.ArgumentParser()
    bench_env.add_arguments(parser)
    args = parser.parse_args(["--benchmark", "smpenvv", "--robots", "walker_2_main"])
    with pytest.raises(ValueError, match="did you mean 'smpenv'"):
        bench_env.run(args)


# ------------------------------------------------------------------ what a video shows


def _first_frame(bench: str, name: str, **kw):
    """(RGB frame, segmentation, model) of the video camera at the start of an episode of
    robot ``name``, at 160 x 120."""
    from gcnt.envs.benchmark import get_benchmark
    from gcnt.envs.render import Filming
    from gcnt.morphology.catalogues import resolve_robots

    env = get_benchmark(bench).make_env(resolve_robots([name]), seed=0, num_threads=1, **kw)
    env.reset()
    try:
        filming = Filming(env, 0, width=160, height=120)
    except Exception as e:
        env.close()
        if no_gl(e):
            pytest.skip(f"no headless OpenGL: {e!r}")
        raise
    try:
        return filming.frame(), filming.segmentation(), filming.model
    finally:
        filming.close()
        env.close()


def _geom_pixels(seg, model, robot: bool):
    """Pixels that show a geom of the robot (else: of the world: floor, walls)."""
    import mujoco
    import numpy as np

    geom = seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)
    body = model.geom_bodyid[np.where(geom, seg[..., 0], 0)]
    return geom & ((body != 0) if robot else (body == 0))


@pytest.mark.parametrize("name", ["hopper_5", "walker_7_main", "humanoid_2d_9_full"])
def test_smpenv_video_shows_the_feet_above_a_floor_not_half_sky(name):
    """The camera frames the whole robot (its lowest pixel well above the bottom edge) and
    looks down on the floor (sky, where no object is, under half the frame); SMPENV's own
    camera, level with the torso, cut hopper_5's foot at the edge and showed 54-59% sky."""
    import numpy as np

    _, seg, model = _first_frame("smpenv", name)
    rows = np.nonzero(_geom_pixels(seg, model, robot=True).any(axis=1))[0]
    assert rows.size and rows.max() < 0.85 * seg.shape[0]
    assert (seg[..., 0] == -1).mean() < 0.5


def test_a_3d_robot_files_world_is_lit():
    """A general 3-D robot's world brings a light (its file's own went with its floor): the
    floor's mean pixel is bright, not the near-black (about 15 of 255) of headlight only."""
    frame, seg, model = _first_frame("mjcf3d", "unimal3d_0000", world="ft")
    floor = _geom_pixels(seg, model, robot=False)
    assert floor.mean() > 0.3
    assert frame[floor].mean() > 45


def _frames(path) -> int:
    imageio = pytest.importorskip("imageio.v2")
    return sum(1 for _ in imageio.get_reader(str(path)))


def test_a_video_is_one_episode_or_the_steps_asked(tmp_path):
    """One episode, to its end (here the 5-step time limit), not a fixed 300 steps; ``steps``
    cuts it shorter. UNIMAL's control rate (50 Hz) gives a frame per step."""
    pytest.importorskip("imageio.v2")
    from gcnt.envs.render import render_rollout
    from gcnt.envs.unimal import UnimalEnv
    from gcnt.morphology.catalogues import resolve_robots

    env = UnimalEnv(resolve_robots(["unimal_0001"]), seed=0, num_threads=1, max_episode_steps=5)
    with gl_or_skip(env):
        whole = render_rollout(env, path=tmp_path / "whole.mp4", width=32, height=32)
        cut = render_rollout(env, steps=3, path=tmp_path / "cut.mp4", width=32, height=32)
    assert (_frames(whole), _frames(cut)) == (5, 3)
    with pytest.raises(ValueError, match="steps must be >= 1"):
        render_rollout(env, steps=0)


def test_eval_video_steps(trained, tmp_path, capsys):
    """``gcnt eval --video`` films one episode (the run's 15-step limit: at most 5 frames at
    SMPENV's 125 Hz, a frame every 3rd step), ``--video-steps N`` at most N steps."""
    import shutil

    from cli_helpers import error_line

    from gcnt.cli import main as gcnt

    run = tmp_path / "run"
    shutil.copytree(trained, run)
    argv = ["eval", str(run), "--video", "--robots", "hopper_3"]
    try:
        assert gcnt(argv) == 0
    except Exception as e:
        if no_gl(e):
            pytest.skip(f"no headless OpenGL: {e!r}")
        raise
    video = run / "videos" / "hopper_3-step40.mp4"
    assert 1 <= _frames(video) <= 5
    assert gcnt([*argv, "--video-steps", "4"]) == 0
    assert _frames(video) == 2
    assert "--video-steps only applies to --video" in error_line(
        capsys, ["eval", str(run), "--video-steps", "4"]
    )
    capsys.readouterr()
    with pytest.raises(SystemExit):
        gcnt([*argv, "--video-steps", "0"])
    assert "must be >= 1" in capsys.readouterr().err


def test_a_video_of_several_robots_tiles_them_until_every_episode_ends(tmp_path):
    """Three robots in one env are filmed side by side (a 2 x 2 grid of 32 x 32 tiles, the
    fourth black); the video lasts until the last episode ends (the 5-step limit)."""
    imageio = pytest.importorskip("imageio.v2")
    from gcnt.envs.render import render_rollout
    from gcnt.envs.unimal import UnimalEnv
    from gcnt.morphology.catalogues import resolve_robots

    robots = resolve_robots(["unimal_0001", "unimal_0002", "unimal_0003"])
    env = UnimalEnv(robots, seed=0, num_threads=1, max_episode_steps=5)
    with gl_or_skip(env):
        path = render_rollout(env, path=tmp_path / "all.mp4", width=64, height=64, index=range(3))
    frames = [f for f in imageio.get_reader(str(path))]  # noqa: C416 (the reader has no len)
    assert len(frames) == 5 and frames[0].shape == (64, 64, 3)
    tiles = [frames[-1][r : r + 32, c : c + 32] for r in (0, 32) for c in (0, 32)]
    assert all(t.std() > 0 for t in tiles[:3])  # each robot's tile shows a scene
    assert tiles[3].max() <= 16  # no fourth robot: black (H.264 may blur the edge)
