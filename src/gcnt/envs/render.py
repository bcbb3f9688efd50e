"""Render a rollout of any benchmark's env to an mp4, headless (MuJoCo's EGL backend), off the hot path.

MuJoCo picks its OpenGL backend when ``mujoco`` is first imported, from ``MUJOCO_GL``, which
``import gcnt`` sets to ``egl`` unless it is set already. If ``mujoco`` was imported before gcnt
with the default GLFW backend on a machine without a display (``$DISPLAY`` unset), this module
switches MuJoCo's classic GL context to EGL before creating a renderer (:func:`headless_gl`).
"""

from __future__ import annotations

import copy
import logging
import os
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np
import torch
from tensordict import TensorDictBase

from gcnt.morphology import Robot

log = logging.getLogger(__name__)

#: Videos are written at the control rate, subsampled to at most this many frames per second.
MAX_FPS = 60


def headless_gl() -> None:
    """Use EGL if MuJoCo chose GLFW but there is no display to open a window on."""
    if os.environ.get("DISPLAY") or os.environ.get("MUJOCO_GL", "").lower() not in ("", "egl"):
        return
    from mujoco.rendering.classic import gl_context

    current = getattr(gl_context, "GLContext", None)
    if current is None or current.__module__.endswith("glfw"):
        from mujoco.egl import GLContext

        gl_context.GLContext = GLContext


def camera_id(model: mujoco.MjModel, camera: str | int) -> int:
    """The id of ``camera`` (a name or an id); -1 (MuJoCo's free camera) if the model lacks it."""
    if isinstance(camera, int):
        return camera if -1 <= camera < model.ncam else -1
    cid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
    if cid < 0:
        log.info("model has no camera %r; rendering with the free camera", camera)
    return int(cid)


def render_rollout(
    env_or_robot,
    policy: Callable[[TensorDictBase], TensorDictBase] | None = None,
    steps: int = 300,
    path: str | Path = "rollout.mp4",
    camera: str | int = "track",
    width: int = 640,
    height: int = 480,
    *,
    index: int = 0,
    seed: int | None = 0,
) -> Path:
    """Roll out ``policy`` (uniform random actions if None) and write sub-env ``index`` as mp4.

    ``env_or_robot`` is a :class:`~gcnt.envs.BatchedMujocoEnv` (its sub-envs all step; episodes
    that end are reset, so the video goes on) or a :class:`~gcnt.morphology.Robot` (a one-robot
    env of its catalogue's benchmark is built with ``seed``). Per-episode model edits (terrain)
    reach the video through the env's ``sync_render`` hook. The camera follows the robot when the robot file has a tracking camera
    (``camera="track"``); width and height should be even (H.264).
    """
    import imageio.v2 as imageio

    from gcnt.envs.benchmark import get_benchmark

    own = isinstance(env_or_robot, Robot)
    if own:
        bench = get_benchmark(env_or_robot.catalogue)
        env = bench.make_env([env_or_robot], seed=seed, num_threads=1)
    else:
        env = env_or_robot
    model, data = env.sim(index)
    rmodel = copy.copy(model)  # a private copy whose offscreen buffer fits the video
    rmodel.vis.global_.offwidth = max(width, rmodel.vis.global_.offwidth)
    rmodel.vis.global_.offheight = max(height, rmodel.vis.global_.offheight)
    cam = camera_id(rmodel, camera)
    dt = float(env.dt[index])
    every = max(1, int(np.ceil((1.0 / dt) / MAX_FPS)))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)

    headless_gl()
    renderer = mujoco.Renderer(rmodel, height=height, width=width)
    try:
        with imageio.get_writer(path, fps=1.0 / (dt * every)) as writer, torch.no_grad():
            td = env.reset()
            for t in range(steps):
                if policy is None:
                    td.update(env.action_spec.rand())
                else:
                    td = policy(td)
                _, td = env.step_and_maybe_reset(td)
                if t % every == 0:
                    env.sync_render(index, rmodel, renderer)
                    renderer.update_scene(data, camera=cam)
                    writer.append_data(renderer.render())
    finally:
        renderer.close()
        if own:
            env.close()
    log.info("wrote %s (%d steps of %s)", path, steps, env.robots[index].name)
    return path
