"""Render a rollout of any benchmark's env to an mp4, headless (MuJoCo's EGL backend), off the hot path.

A video is one episode (or fewer steps, if asked), filmed by a camera that follows the robot from
its side and a little above, framing its whole body over the floor (:class:`FollowCamera`), in
any benchmark and world; a camera of the model can be asked for by name instead.

MuJoCo picks its OpenGL backend when ``mujoco`` is first imported, from ``MUJOCO_GL``, which
``import gcnt`` sets to ``egl`` unless it is set already. If ``mujoco`` was imported before gcnt
with the default GLFW backend on a machine without a display (``$DISPLAY`` unset), this module
switches MuJoCo's classic GL context to EGL before creating a renderer (:func:`headless_gl`).
"""

from __future__ import annotations

import copy
import logging
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import mujoco
import numpy as np
import torch
from tensordict import TensorDictBase

from gcnt.files import temp_path
from gcnt.morphology import Robot

log = logging.getLogger(__name__)

#: Videos are written at the control rate, subsampled to at most this many frames per second.
MAX_FPS = 60
#: the most robots one video tiles (the first ones of the env)
MAX_TILES = 16
#: the near and far clipping planes of every video, metres
NEAR_CLIP, FAR_CLIP = 0.05, 400.0


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


class FollowCamera:
    """The video camera: beside the robot (on its −y side, looking along +y, so that walking
    along +x goes to the right), a little above it, following its centre of mass.

    Its distance is set once from the robot's size at the start, so that the whole robot fills
    about :data:`FILL` of the frame's height; it looks at the middle of the robot's height (the
    centre of mass shifted down by its height above that middle at the start), so the feet stay
    in the frame, and down at :data:`ELEVATION` degrees, so the floor fills most of the frame.
    """

    #: degrees below the horizon the camera looks
    ELEVATION = -20.0
    #: the share of the frame's height the robot's largest size takes
    FILL = 0.4
    #: the nearest the camera comes, metres
    MIN_DISTANCE = 2.0

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, root_body: int):
        self.data, self.root = data, int(root_body)
        self.geoms = np.nonzero(model.body_rootid[model.geom_bodyid] == self.root)[0]
        self.aabb = model.geom_aabb[self.geoms]  # local centre and half-sizes of each geom
        lo, hi = self.bounds()
        half_fov = np.radians(model.vis.global_.fovy) / 2.0
        size = float((hi - lo).max())
        self.cam = mujoco.MjvCamera()
        self.cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        self.cam.distance = max(self.MIN_DISTANCE, size / (2.0 * self.FILL * np.tan(half_fov)))
        self.cam.azimuth, self.cam.elevation = 90.0, self.ELEVATION
        self.drop = float(data.subtree_com[self.root, 2] - (lo[2] + hi[2]) / 2.0)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The world-frame box around the robot's geoms now: (lowest corner, highest corner)."""
        rot = self.data.geom_xmat[self.geoms].reshape(-1, 3, 3)
        centre = self.data.geom_xpos[self.geoms] + np.einsum("gij,gj->gi", rot, self.aabb[:, :3])
        half = np.einsum("gij,gj->gi", np.abs(rot), self.aabb[:, 3:])
        return (centre - half).min(axis=0), (centre + half).max(axis=0)

    def update(self) -> mujoco.MjvCamera:
        """The camera for the robot's current pose."""
        self.cam.lookat[:] = self.data.subtree_com[self.root] - (0.0, 0.0, self.drop)
        return self.cam


class Filming:
    """Frames of sub-env ``index`` of a batched env: RGB pictures and, for checks, what object
    each pixel shows. ``camera``: None for the :class:`FollowCamera`, else a camera of the model
    (a name or an id; a missing one falls back to MuJoCo's free camera)."""

    def __init__(
        self,
        env,
        index: int = 0,
        camera: str | int | None = None,
        width: int = 640,
        height: int = 480,
    ):
        self.env, self.index = env, index
        model, self.data = env.sim(index)
        self.model = copy.copy(model)  # a private copy whose offscreen buffer fits the video
        self.model.vis.global_.offwidth = max(width, self.model.vis.global_.offwidth)
        self.model.vis.global_.offheight = max(height, self.model.vis.global_.offheight)
        # MuJoCo's clipping planes scale with the model's extent, which parked obstacle boxes
        # (1 km away) make so large that the near plane would cut the robot away: set in metres
        extent = float(self.model.stat.extent)
        self.model.vis.map.znear = NEAR_CLIP / extent
        self.model.vis.map.zfar = FAR_CLIP / extent
        self.camera = camera
        # a named camera is looked up once (a missing one is reported once)
        self._camera_id = camera_id(self.model, camera) if camera is not None else None
        self._follow: FollowCamera | None = None
        headless_gl()
        self.renderer = mujoco.Renderer(self.model, height=height, width=width)

    def _camera(self) -> mujoco.MjvCamera | int:
        if self._camera_id is not None:
            return self._camera_id
        if self._follow is None:  # placed at the first frame, from the robot's start pose
            root = int(self.env.robots[self.index].mj_body_ids[0])
            self._follow = FollowCamera(self.model, self.data, root)
        return self._follow.update()

    def _scene(self) -> None:
        self.env.sync_render(self.index, self.model, self.renderer)
        # lights and cameras where the bodies are now (a reset leaves them where they were)
        mujoco.mj_camlight(self.model, self.data)
        self.renderer.update_scene(self.data, camera=self._camera())

    def frame(self) -> np.ndarray:
        """The picture now: uint8 [height, width, 3]."""
        self._scene()
        return self.renderer.render()

    def segmentation(self) -> np.ndarray:
        """What each pixel shows now: int [height, width, 2], (object id, ``mjtObj`` type); id
        -1 where no object is (the sky)."""
        self._scene()
        self.renderer.enable_segmentation_rendering()
        try:
            return self.renderer.render()
        finally:
            self.renderer.disable_segmentation_rendering()

    def close(self) -> None:
        self.renderer.close()


def render_rollout(
    env_or_robot,
    policy: Callable[[TensorDictBase], TensorDictBase] | None = None,
    steps: int | None = None,
    path: str | Path = "rollout.mp4",
    camera: str | int | None = None,
    width: int = 640,
    height: int = 480,
    *,
    index: int | Sequence[int] = 0,
    seed: int | None = 0,
) -> Path:
    """Roll out ``policy`` (uniform random actions if None) and write sub-env ``index`` as mp4:
    one episode, from a reset until it ends (the robot falls, or the env's episode length), or
    ``steps`` control steps if fewer. Several indices (at most :data:`MAX_TILES`) are filmed side
    by side in a grid of ``width`` x ``height``, each until its own episode ends (then its last
    picture stays), the video until every one has ended.

    ``env_or_robot`` is a :class:`~gcnt.envs.BatchedMujocoEnv` (its sub-envs all step; others
    whose episodes end are reset) or a :class:`~gcnt.morphology.Robot` (a one-robot env of its
    catalogue's benchmark is built with ``seed``). Per-episode model edits (terrain) reach the
    video through the env's ``sync_render`` hook. ``camera``: None follows the robot
    (:class:`FollowCamera`); a camera name or id of the model films through that camera. Width
    and height should be even (H.264).
    """
    import imageio.v2 as imageio

    from gcnt.envs.benchmark import get_benchmark

    if steps is not None and steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    indices = [index] if isinstance(index, int) else list(index)[:MAX_TILES]
    if not indices:
        raise ValueError("no sub-env to film")
    own = isinstance(env_or_robot, Robot)
    if own:
        bench = get_benchmark(env_or_robot.catalogue)
        env = bench.make_env([env_or_robot], seed=seed, num_threads=1)
    else:
        env = env_or_robot
    dt = float(env.dt[indices[0]])
    every = max(1, int(np.ceil((1.0 / dt) / MAX_FPS)))
    limit = env.max_episode_steps if steps is None else steps  # an episode ends by then
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cols = int(np.ceil(np.sqrt(len(indices))))
    rows = -(-len(indices) // cols)
    tile_w, tile_h = (width // cols) & ~1, (height // rows) & ~1  # even, for H.264
    films = [Filming(env, i, camera, tile_w, tile_h) for i in indices]
    last: list[np.ndarray | None] = [None] * len(indices)  # an ended episode's last picture
    shown: list[np.ndarray] = []
    t = 0
    try:
        with (
            temp_path(path) as tmp,
            imageio.get_writer(tmp, fps=1.0 / (dt * every)) as writer,
            torch.no_grad(),
        ):
            td = env.reset()
            # each frame shows the state before a step; the state an episode ends in is not
            # filmed, as the env resets the sub-env in the same call
            for t in range(limit):
                if t % every == 0:
                    shown = [
                        p if p is not None else f.frame() for p, f in zip(last, films, strict=True)
                    ]
                    writer.append_data(_grid(shown, cols, rows) if len(films) > 1 else shown[0])
                if policy is None:
                    td.update(env.action_spec.rand())
                else:
                    td = policy(td)
                td, td_next = env.step_and_maybe_reset(td)
                done = td["next", "done"].reshape(env.batch_size[0], -1).any(-1)
                for k, i in enumerate(indices):
                    if last[k] is None and bool(done[i]):  # its picture before the reset stays
                        last[k] = shown[k]
                if all(p is not None for p in last):
                    break
                td = td_next
    finally:
        for f in films:
            f.close()
        if own:
            env.close()
    names = ", ".join(env.robots[i].name for i in indices)
    log.info("wrote %s (%d steps of %s)", path, t + 1, names)
    return path


def _grid(pictures: list[np.ndarray], cols: int, rows: int) -> np.ndarray:
    """Pictures of one size tiled row by row into ``rows`` x ``cols`` (black where none is)."""
    h, w, c = pictures[0].shape
    out = np.zeros((rows * h, cols * w, c), dtype=pictures[0].dtype)
    for k, p in enumerate(pictures):
        r, q = divmod(k, cols)
        out[r * h : (r + 1) * h, q * w : (q + 1) * w] = p
    return out
