"""``gcnt eval RUN_DIR [--robots test|train|NAME|PATH ...] [--episodes N]
[--deterministic | --stochastic]``.

Actions follow the run's recipe (``eval.deterministic``: the policy's mean action, or sampled
actions as in ModuMorph's PPO protocol) unless a flag says otherwise; the episodes default to
100 deterministic or 32 sampled ones per robot. Every evaluation is kept:
``eval/<robots>-step<N>-<det|stoch>-seed<S>.json`` in the run directory says what was evaluated
(robots, episodes, seed, deterministic or sampled actions); ``<robots>`` carries a short hash of
the exact list where the name alone would be ambiguous (robot files, replaced characters). A run
directory that cannot be written (read-only, full) still lets ``--json PATH`` keep the result.
"""

from __future__ import annotations

import argparse
import hashlib
import logging
import re
from pathlib import Path

from gcnt.commands.options import add_eval_protocol
from gcnt.suggest import existing_path

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", help="a run directory written by `gcnt train`")
    p.add_argument(
        "--robots",
        nargs="+",
        default=["test"],
        help="test | train | robot names | robot files or folders | Benchmark:split "
        "(default: test)",
    )
    p.add_argument(
        "--episodes",
        type=int,
        default=None,
        help="episodes per robot (default: 100 deterministic, 32 stochastic)",
    )
    p.add_argument("--seed", type=int, default=10_000, help="evaluation seed")
    add_eval_protocol(p, "deterministic")
    p.add_argument("--json", metavar="PATH", help="also write the results to PATH")
    p.add_argument(
        "--video",
        action="store_true",
        help="instead of evaluating, record one deterministic episode per robot to "
        "videos/<robot>-step<N>.mp4 (the recipe and evaluations are left as they are)",
    )
    p.add_argument(
        "--video-steps",
        type=_positive_int,
        default=None,
        metavar="N",
        help="with --video: at most N control steps per video (default: the whole episode, "
        "until the robot falls or env.max_episode_steps)",
    )


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def protocol(recipe, deterministic: bool | None) -> bool:
    """Deterministic actions or not: as asked, else as the recipe's ``eval.deterministic``."""
    return bool(recipe.eval.deterministic) if deterministic is None else deterministic


def default_episodes(deterministic: bool) -> int:
    """Episodes per robot when none are asked for: the paper's 100 deterministic episodes, or
    ModuMorph's 32 with sampled actions."""
    return 100 if deterministic else 32


def resolved_spec(spec: str) -> str:
    """What a robot spec names, independent of the working folder: a robot file or folder as
    its resolved path and a hash of its content (every robot file of a folder), anything else
    (a robot name, ``Benchmark:split``, a pattern) as typed."""
    from gcnt.files import read_regular
    from gcnt.morphology.robot import MAX_ROBOT_FILE_BYTES

    path = Path(spec)
    try:
        if path.is_file():
            files = [path]
        elif path.is_dir():
            files = sorted(p for p in path.iterdir() if p.suffix == ".xml" and p.is_file())
        else:
            return spec
        digest = hashlib.sha256()
        for f in files:  # read as the robot loader reads them: regular files of a sane size
            data = read_regular(f, MAX_ROBOT_FILE_BYTES, "a robot file is MJCF XML", OSError)
            digest.update(f.name.encode() + b"\0" + data + b"\0")
        return f"{path.resolve()}#{digest.hexdigest()[:16]}"
    except OSError:
        return spec


def _label(specs: list[str], resolved: list[str] | None = None) -> str:
    """The evaluation file's name for robot ``specs``: the specs themselves (robot names,
    ``Benchmark:split`` as ``Benchmark-split``) where that is exact; with a short hash of what
    they name (``resolved``, from :func:`resolved_spec`: files by resolved path and content)
    appended where the name lost something (a file's folder, a character replaced, a long list
    cut), so that different robot sets never share a file (``"a b.xml"`` and ``a_b.xml``; the
    same relative path typed in two working folders)."""
    text = "+".join(Path(s).stem if s.endswith(".xml") else s for s in specs)
    label = re.sub(r"[^A-Za-z0-9_.+-]+", "_", text.replace(":", "-"))[:80] or "robots"
    exact = all(
        re.fullmatch(r"[A-Za-z0-9_.+-]+(:[A-Za-z0-9_.+-]+)?", s) and not s.endswith(".xml")
        for s in specs
    )
    if exact and len(text) <= 80 and (resolved is None or resolved == specs):
        return label
    digest = hashlib.sha1("\n".join(resolved or specs).encode()).hexdigest()[:8]
    return f"{label}-{digest}"


def _run_recipe(path: Path):
    """The recipe of the run directory ``path``, read without loading torch, so that mistakes in
    what to evaluate are reported before anything heavy is loaded."""
    from gcnt.analysis.runs import RECIPE_FILE
    from gcnt.run.record import load_run_recipe

    if not (path / RECIPE_FILE).exists():
        raise FileNotFoundError(f"{path}: no {RECIPE_FILE}; is this a gcnt run directory?")
    return load_run_recipe(path / RECIPE_FILE, anywhere=True, stored_robots=False)


def run(args: argparse.Namespace) -> int:
    from gcnt.analysis.runs import protocol_text
    from gcnt.recipes import RecipeError

    if args.video_steps is not None and not args.video:
        raise RecipeError("--video-steps only applies to --video")
    path = existing_path(args.run_dir)
    recipe = _run_recipe(path)
    deterministic = protocol(recipe, args.deterministic)
    episodes = args.episodes if args.episodes is not None else default_episodes(deterministic)
    if episodes < 1:
        raise RecipeError(f"--episodes must be >= 1, got {episodes}")
    if not any(
        recipe.env.test_robots if s == "test" else recipe.env.robots if s == "train" else [s]
        for s in args.robots
    ):
        raise RecipeError(
            f"{path}: no robots to evaluate (the recipe has no test robots; pass --robots ...)"
        )
    from gcnt.run.record import use_stored_robots

    use_stored_robots(recipe, path)  # the run's own robots where not registered here
    if args.json:  # a folder or a socket there: refused before the evaluation
        from gcnt.files import check_output

        check_output(args.json)
    specs: list[str] = []
    for spec in args.robots:
        if spec == "test":
            specs += recipe.env.test_robots
        elif spec == "train":
            specs += recipe.env.robots
        else:
            specs.append(spec)
    from gcnt.morphology.catalogues import resolve_robots
    from gcnt.recipes import run_robot_specs

    # unknown names, bad files: before torch loads; named as in the run's own robot lists, each
    # spec looked up once in this command (the run's record below reuses what is looked up here)
    lookups: dict = {}
    robots = resolve_robots(
        specs, repeats=True, names_from=run_robot_specs(recipe), lookups=lookups
    )
    if not robots:
        raise RecipeError(f"{path}: no robots to evaluate ({', '.join(specs)} name none)")
    from gcnt.rl.evaluate import PolicyMismatchError, evaluate, format_table, write_eval
    from gcnt.run.directory import CheckpointError, RunDir, RunDirError
    from gcnt.run.resolved import check_benchmark, resolve_run

    run_dir = RunDir(path)
    resolve_run(recipe, lookups=lookups)  # the network, benchmark and robots the run names
    check_benchmark(recipe, robots, f"--robots of run {run_dir.path}")
    run_dir.check_links()  # a link out of the run directory is refused before any work
    state = run_dir.load_checkpoint()
    if "policy" not in state and "actor" not in state:
        raise CheckpointError(f"{run_dir.checkpoint_path}: no policy; not a checkpoint gcnt wrote")
    policy = state.get("policy") or {"actor": state["actor"]}  # "actor": checkpoints before 0.2
    if args.video:
        return _videos(recipe, run_dir, policy, robots, state["env_steps"], args.video_steps)
    try:
        results = evaluate(
            recipe, policy, specs, episodes=episodes, seed=args.seed, deterministic=deterministic
        )
    except PolicyMismatchError as e:
        raise CheckpointError(f"{run_dir.checkpoint_path}: {e}") from None
    print(protocol_text(deterministic, episodes))
    print(format_table(results))
    resolved = [s if s in ("test", "train") else resolved_spec(s) for s in args.robots]
    meta = {
        "robots_spec": args.robots,
        "resolved_specs": specs,
        # robot files and folders by resolved path and content hash
        "resolved_files": {s: r for s, r in zip(args.robots, resolved, strict=True) if r != s},
        "episodes": episodes,
        "seed": args.seed,
        "deterministic": deterministic,
    }
    mode = "det" if deterministic else "stoch"
    name = f"{_label(args.robots, resolved)}-step{state['env_steps']}-{mode}-seed{args.seed}.json"
    steps = state["env_steps"]
    failed = None
    try:
        print(f"written: {write_eval(run_dir.eval_dir() / name, results, steps, meta)}")
    except RunDirError as e:  # a read-only or full run directory: --json is still written
        failed = e
    if args.json:
        print(f"written: {write_eval(Path(args.json), results, steps, meta, named=True)}")
    if failed is not None and not args.json:
        raise RunDirError(f"{failed}; the results are printed above (--json PATH keeps them)")
    if failed is not None:
        log.warning("%s; the results were written to %s only", failed, args.json)
    return 0


def _videos(recipe, run_dir, policy: dict, robots: list, env_steps: int, steps: int | None) -> int:
    """One deterministic episode per robot (at most ``steps`` control steps), as a video under
    the run's ``videos/``."""
    from gcnt.rl.evaluate import render_policy

    for robot in robots:
        path = run_dir.inside("videos") / f"{robot.name}-step{env_steps}.mp4"
        print(f"written: {render_policy(recipe, policy, path, robot=robot, steps=steps)}")
    return 0
