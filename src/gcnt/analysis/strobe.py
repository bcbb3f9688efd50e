"""A strobe picture of rollouts (paper figure 11): poses along the path, a row per run.

Each run's deterministic policy drives one robot (by default ``humanoid_2d_9_full``) for up to
``steps`` control steps or until its episode ends. Up to ``frames`` poses are drawn into one
MuJoCo scene (earlier poses fainter), rendered headless (``MUJOCO_GL=egl``) from the side by a
orthographic camera, over a light floor marked with a line every metre (or 0.25 ... 100 m, as
the view needs) along x, each labelled with its distance. The poses are evenly spaced in time when the root
travels far enough for them to stand apart; otherwise (a policy that barely moves) they are
chosen by the root's x position, at least ``min_gap`` metres apart, so that they do not pile up
into one blob. All rows share one camera, so the distance marks line up from row to row.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gcnt.analysis.plotting import FigureStyle
from gcnt.analysis.runs import AnalysisError, Run

DEFAULT_ROBOT = "humanoid_2d_9_full"


def _policy_and_env(run: Run, robot: str, seed: int):
    """The run's trained deterministic policy and a one-robot env for ``robot``."""
    from gcnt.rl.algorithm import get_algorithm
    from gcnt.rl.factories import make_env
    from gcnt.run.directory import RunDir
    from gcnt.run.resolved import resolve_run

    recipe = RunDir(run.path).load_recipe(anywhere=True)
    policy_state = run.policy_state()
    record = resolve_run(recipe)
    robots = record.robots_of([robot], recipe)
    train_k = recipe.env.max_limbs or max(r.num_limbs for r in record.train_robots)
    max_limbs = max(train_k, *(r.num_limbs for r in robots))
    env = make_env(recipe, robots, seed=seed, max_limbs=max_limbs, num_threads=1)
    policy = get_algorithm(recipe.algo).eval_policy(recipe, policy_state, env, deterministic=True)
    return policy, env


def rollout_poses(run: Run, robot: str = DEFAULT_ROBOT, steps: int = 300, seed: int = 0):
    """(model, data, qpos per step [T, nq], episode return) of one deterministic rollout."""
    import torch
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    policy, env = _policy_and_env(run, robot, seed)
    model, data = getattr(env, "base_env", env).sim(0)  # under the TransformedEnv
    poses = []
    ret = 0.0
    td = env.reset()
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(steps):
            td = policy(td)
            td, td_next = env.step_and_maybe_reset(td)
            poses.append(data.qpos.copy())
            ret += float(td["next", "reward"].sum())
            if bool(td["next", "done"].any()):
                break
            td = td_next
    return env, model, data, np.stack(poses), ret


#: least root x distance (m) between drawn poses when the poses are chosen by position
MIN_GAP = 0.3
#: colours (RGBA) of the scene around the robot
FLOOR_RGBA = (0.93, 0.93, 0.91, 1.0)
LINE_RGBA = (0.35, 0.35, 0.4, 1.0)
MINOR_RGBA = (0.65, 0.65, 0.7, 1.0)
#: elevation (degrees, negative: looking down) of the orthographic side camera
ELEVATION = -15.0
#: half-depth (m, along y) of the marked floor strip
STRIP = 0.6


def root_x(model, data, poses: np.ndarray) -> np.ndarray:
    """x of the root body (the first body under the world) at each pose."""
    import mujoco

    root = 1 if model.nbody > 1 else 0
    xs = np.empty(len(poses), dtype=np.float64)
    for t, q in enumerate(poses):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        xs[t] = data.xpos[root, 0]
    return xs


def strobe_frames(x: np.ndarray, frames: int = 8, min_gap: float = MIN_GAP) -> np.ndarray:
    """Indices of the poses to draw, given the root's x per step.

    Evenly spaced in time when the root's x range is at least ``min_gap * (frames - 1)``; else
    picked back from the last step, each at least ``min_gap`` in x from the one picked before
    (the last pose is always drawn, at most ``frames`` poses).
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 1 or len(x) == 0:
        raise ValueError(f"strobe_frames needs a non-empty 1-d array of root x, got {x.shape}")
    frames = max(1, int(frames))
    if np.ptp(x) >= min_gap * (frames - 1):
        return np.unique(np.linspace(0, len(x) - 1, frames).round().astype(int))
    picked = [len(x) - 1]
    for t in range(len(x) - 2, -1, -1):
        if len(picked) == frames:
            break
        if abs(x[t] - x[picked[-1]]) >= min_gap:
            picked.append(t)
    return np.array(picked[::-1])


def pose_extent(model, data, poses: np.ndarray, frames: Sequence[int]) -> np.ndarray:
    """(x low, x high, z high) in metres of the robot's geoms over the poses ``frames``."""
    import mujoco

    own = model.geom_bodyid > 0
    lo, hi, top = np.inf, -np.inf, 0.0
    for i in frames:
        data.qpos[:] = poses[int(i)]
        mujoco.mj_kinematics(model, data)
        pos, r = data.geom_xpos[own], model.geom_rbound[own]
        lo, hi = min(lo, float((pos[:, 0] - r).min())), max(hi, float((pos[:, 0] + r).max()))
        top = max(top, float((pos[:, 2] + r).max()))
    return np.array([lo, hi, top])


def _nice_step(span: float, marks: int = 8) -> float:
    """A distance between floor lines (0.25, 0.5, 1, 2, 5, 10 ... m) giving at most ``marks``."""
    for step in (0.25, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0):
        if span / step <= marks:
            return step
    return 100.0


def _add_geom(scene, kind, size, pos, rgba, label: str = "", emission: float = 0.0) -> None:
    import mujoco

    if scene.ngeom >= scene.maxgeom:
        return
    g = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(
        g,
        kind,
        np.asarray(size, dtype=np.float64),
        np.asarray(pos, dtype=np.float64),
        np.eye(3).ravel(),
        np.asarray(rgba, dtype=np.float32),
    )
    g.label = label
    g.emission = emission
    scene.ngeom += 1


def _add_floor(scene, x_range: tuple[float, float], far: float) -> None:
    """A light floor, lines across the floor strip every ``step`` m (labelled with their x) and
    halfway between, and the strip's edges."""
    import mujoco

    box = mujoco.mjtGeom.mjGEOM_BOX
    lo, hi = x_range
    mid = (lo + hi) / 2
    _add_geom(scene, box, (far, far, 0.001), (mid, 0.0, -0.001), FLOOR_RGBA, emission=0.4)
    step = _nice_step(hi - lo)
    first = np.ceil(lo / step) * step
    for k in range(int(np.floor((hi - first) / step)) + 1):
        x = first + k * step
        _add_geom(scene, box, (0.012, STRIP, 0.001), (x, 0.0, 0.001), LINE_RGBA)
        if x < hi - step / 4:  # a label needs room on the line's right
            label = f"{x:g} m"
            _add_geom(scene, box, (0.0, 0.0, 0.0), (x + 0.02, -STRIP, 0.002), LINE_RGBA, label)
        if x + step / 2 < hi:
            _add_geom(scene, box, (0.006, STRIP, 0.001), (x + step / 2, 0.0, 0.001), MINOR_RGBA)
    for y in (-STRIP, STRIP):
        _add_geom(scene, box, ((hi - lo) / 2, 0.006, 0.001), (mid, y, 0.001), MINOR_RGBA)


def strobe_image(
    model,
    data,
    poses: np.ndarray,
    frames: Sequence[int],
    *,
    view: Sequence[float] | None = None,
    width: int = 1280,
) -> np.ndarray:
    """RGB image [H, W, 3] of the poses ``frames`` in one scene seen from the side.

    The camera frames ``view`` = (x low, x high, z high) in metres (default: the
    :func:`pose_extent` of the drawn poses) with a margin, orthographically (distances read the
    same everywhere in the picture); the image height follows the view's aspect (between a sixth
    and a third of ``width``).
    """
    import copy

    import mujoco

    from gcnt.envs.render import headless_gl

    idx = [int(i) for i in frames]
    lo, hi, top = view if view is not None else pose_extent(model, data, poses, idx)
    margin = 0.5 * max(top, 0.5)
    across, up = (hi - lo) + 2 * margin, top + margin
    height = int(np.clip(width * up / across, width / 6, width / 3)) // 2 * 2
    vertical = max(up, across * height / width)  # metres seen from bottom to top
    distance = 2 * (across + up) + 5.0  # in front of everything drawn
    rmodel = copy.copy(model)
    rmodel.vis.global_.offwidth = max(width, rmodel.vis.global_.offwidth)
    rmodel.vis.global_.offheight = max(height, rmodel.vis.global_.offheight)
    rmodel.vis.global_.orthographic = 1  # the free camera's projection
    rmodel.vis.global_.fovy = vertical  # an orthographic camera's fovy is its height in metres
    rmodel.vis.map.znear = 0.01
    rmodel.vis.map.zfar = 4 * distance / max(rmodel.stat.extent, 1e-6)
    rmodel.light_active[:] = 0  # even headlight only: no spotlight circle, no shadows
    rmodel.vis.headlight.ambient[:] = 0.5
    rmodel.vis.headlight.diffuse[:] = 0.5
    rmodel.vis.headlight.specular[:] = 0.1
    # the scene's own floor (added last) replaces the model's ground planes
    planes = (rmodel.geom_bodyid == 0) & (rmodel.geom_type == mujoco.mjtGeom.mjGEOM_PLANE)
    rmodel.geom_rgba[planes, 3] = 0.0
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.orthographic = 1
    cam.lookat[:] = ((lo + hi) / 2, 0.0, up / 2 - margin / 2)
    cam.distance = distance
    cam.azimuth, cam.elevation = 90.0, ELEVATION
    headless_gl()
    renderer = mujoco.Renderer(rmodel, height=height, width=width, max_geom=20000)
    try:
        opt = mujoco.MjvOption()
        pert = mujoco.MjvPerturb()
        data.qpos[:] = poses[idx[-1]]
        mujoco.mj_forward(model, data)
        renderer.update_scene(data, camera=cam, scene_option=opt)
        scene = renderer.scene
        for n, i in enumerate(idx[:-1]):
            data.qpos[:] = poses[i]
            mujoco.mj_forward(model, data)
            start = scene.ngeom
            mujoco.mjv_addGeoms(model, data, opt, pert, mujoco.mjtCatBit.mjCAT_DYNAMIC, scene)
            alpha = 0.25 + 0.6 * n / max(1, len(idx) - 1)
            for g in range(start, scene.ngeom):
                scene.geoms[g].rgba[3] = alpha
        half = vertical * width / height / 2
        _add_floor(scene, (cam.lookat[0] - half, cam.lookat[0] + half), distance)
        return renderer.render().copy()
    finally:
        renderer.close()


def strobe_figure(
    images: Sequence[np.ndarray],
    labels: Sequence[str],
    title: str | None = None,
    style: FigureStyle | None = None,
):
    """One figure with a row per image, each labelled on its left; size, fonts and title (over
    ``title``) as ``style`` says."""
    if len(images) != len(labels) or not images:
        raise ValueError(f"{len(images)} images for {len(labels)} row labels")
    style = style or FigureStyle()
    with style.context():
        return _strobe_figure(images, labels, title, style)


def _strobe_figure(
    images: Sequence[np.ndarray], labels: Sequence[str], title: str | None, style: FigureStyle
):
    from gcnt.analysis.plotting import pyplot

    plt = pyplot()
    h, w = images[0].shape[:2]
    width = 9.0
    size = style.size((width + 1.4, width * h / w * len(images) + 0.5))
    fig, axes = plt.subplots(len(images), 1, figsize=size, squeeze=False)
    for ax, image, label in zip(axes[:, 0], images, labels, strict=True):
        ax.imshow(image)
        ax.set_xticks([])
        ax.set_yticks([])
        for spine in ax.spines.values():
            spine.set_visible(False)
        ax.set_ylabel(label, rotation=0, ha="right", va="center", fontsize="medium")
    style.suptitle(fig, title, fontsize="medium")
    fig.tight_layout(h_pad=0.3)
    return fig


def strobe_runs(
    runs: Sequence[Run],
    out: Path,
    *,
    robot: str = DEFAULT_ROBOT,
    steps: int = 300,
    frames: int = 8,
    seed: int = 0,
    min_gap: float = MIN_GAP,
    name: str | None = None,
    style: FigureStyle | None = None,
) -> Path:
    """One picture of ``runs`` (a row each, labelled with its method's display name) on
    ``robot``, as ``out/<name>.png`` (default ``strobe-<robot>-<task>[-<task>...]``; the
    formats, size and fonts as ``style`` says); returns the first file written."""
    from gcnt.analysis.runs import method_labels

    style = style or FigureStyle()

    if not runs:
        raise AnalysisError("no run to draw")
    for r in runs:
        if not r.has_checkpoint():
            raise AnalysisError(f"{r.path}: no checkpoint to take the policy from")
    labels = method_labels(runs)
    several_tasks = len({r.task for r in runs}) > 1
    shown = [style.name(labels[r.path]) for r in runs]
    if several_tasks:
        shown = [f"{text} ({style.name(r.task)})" for text, r in zip(shown, runs, strict=True)]
    rows = []
    for r in runs:
        env, model, data, poses, ret = rollout_poses(r, robot, steps, seed)
        try:
            xs = root_x(model, data, poses)
            rows.append((model, data, poses, xs, ret))
        finally:
            env.close()
    picks = [strobe_frames(xs, frames, min_gap) for _, _, _, xs, _ in rows]
    ext = np.array(
        [pose_extent(m, d, p, i) for (m, d, p, _, _), i in zip(rows, picks, strict=True)]
    )
    view = (ext[:, 0].min(), ext[:, 1].max(), ext[:, 2].max())  # one camera for all rows
    images, row_labels = [], []
    for r, text, idx, (model, data, poses, xs, ret) in zip(runs, shown, picks, rows, strict=True):
        images.append(strobe_image(model, data, poses, idx, view=view))
        seed_note = f", seed {r.seed}" if shown.count(text) > 1 else ""
        row_labels.append(
            f"{text}{seed_note}\nreturn {ret:.0f}\n{len(poses)} steps\nx {xs[-1] - xs[0]:+.2f} m"
        )
    tasks = "-".join(dict.fromkeys(r.task for r in runs))
    robot_name = Path(robot).stem  # a robot given by its file: the file's name
    stem = name or f"strobe-{robot_name}-{tasks}".replace("+", "p")
    title = f"{robot_name}: deterministic policy, poses along the path"
    fig = strobe_figure(images, row_labels, title=title, style=style)
    return style.save(fig, out / f"{stem}.png")[0]
