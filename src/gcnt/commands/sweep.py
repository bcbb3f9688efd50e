"""``gcnt sweep RECIPE... [--methods gcnt,swat] [--seeds 0,1,2] [key=value ...]``.

Runs a grid of recipes x methods x seeds as ``gcnt train`` runs under one sweep directory
(``--dir``, default ``sweeps/<task>``), locally in a pool of pinned slots or on Slurm through
submitit. Running the same command again (or ``gcnt sweep SWEEP_DIR``) skips finished runs and
resumes unfinished ones. ``--eval test`` evaluates each trained run on its test robots.

Overrides apply to every run; ``METHOD:key=value`` to one method only
(e.g. ``swat:network.kwargs.max_limbs=16``). ``--per-robot SPLIT`` makes one run per robot of the
split, each trained alone (single-robot baselines: SR-fair, SR-top).
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

from gcnt.commands.options import add_eval_protocol

log = logging.getLogger(__name__)


def _csv(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def _seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in _csv(text):
        if "-" in part[1:]:
            a, b = part.split("-", 1)
            out += list(range(int(a), int(b) + 1))
        else:
            out.append(int(part))
    return out


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = __doc__.split("\n\n")[1]
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = (
        "examples:\n"
        "  gcnt sweep recipes/smpenv/walker.yaml --methods gcnt,swat,amorpheus --seeds 0,1,2\n"
        "  gcnt sweep recipes/smpenv/*.yaml --methods gcnt,swat --seeds 0-2 --eval test\n"
        "  gcnt sweep sweeps/walkerpp                  # resume: skip done, resume partial\n"
        "  gcnt sweep sweeps/walkerpp --status\n"
        "  gcnt sweep recipes/smpenv/cwhh.yaml --seeds 0-3 --slurm --partition gpu \\\n"
        "      --gpus-per-run 1 --cpus-per-run 8 --time 2880\n"
        "  gcnt sweep recipes/unimal/sr_fair.yaml --per-robot Unimal:train --seeds 0-3 \\\n"
        "      --dir sweeps/unimal-ft-sr                # one SR run per training robot"
    )
    p.add_argument(
        "items",
        nargs=argparse.REMAINDER,
        metavar="RECIPE|SWEEP_DIR|key=value",
        help="recipe files, or one sweep directory to continue; overrides key=value (options "
        "may come before, between or after them)",
    )
    _options(p)


def _options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--methods", type=_csv, help="comma-separated methods (default: the recipe's)")
    p.add_argument("--seeds", type=_seeds, help="seeds: 0,1,2 or 0-2 (default: the recipe's)")
    p.add_argument("--dir", type=Path, help="sweep directory (default: sweeps/<task>)")
    p.add_argument(
        "--per-robot",
        metavar="SPLIT",
        help="one run per robot of SPLIT (Unimal:train, a robot, robot1,robot2, ...), each "
        "trained alone: env.robots=[ROBOT] env.test_robots=[]; run ids "
        "<task>/<algo>-<method or the recipe's label>/<robot>/seed<N>",
    )
    p.add_argument(
        "--group",
        help="W&B group prefix: runs are grouped as GROUP/<task>/<algo>-<method> (default "
        "GROUP: the sweep directory's name); every run is tagged sweep:<sweep directory's name>",
    )
    p.add_argument(
        "--eval",
        action="append",
        default=[],
        metavar="ROBOTS",
        help="after training, `gcnt eval RUN --robots ROBOTS` (test, train, a robot, "
        "Benchmark:split); repeatable",
    )
    p.add_argument(
        "--episodes",
        type=int,
        default=None,
        help="episodes per robot for --eval (default: gcnt eval's, 100 deterministic or 32 "
        "sampled)",
    )
    add_eval_protocol(p, "eval_deterministic", "--eval with ")
    p.add_argument("--status", action="store_true", help="print the manifest's states and exit")
    p.add_argument("--dry-run", action="store_true", help="write the manifest, print, run nothing")
    local = p.add_argument_group("local pool")
    local.add_argument("--jobs", type=int, help="runs at a time (default: cores / cpus-per-run)")
    local.add_argument(
        "--stack-seeds",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="train the seeds of each TD3 method in one process (gcnt train --seeds: one "
        "vmapped update); default: on when the runs train on a CUDA device, where separate "
        "processes take turns on the GPU",
    )
    local.add_argument(
        "--cpus-per-run", type=int, default=1, help="cores (and threads) per run (default 1)"
    )
    slurm = p.add_argument_group("Slurm (through submitit: one job array, one run per task)")
    slurm.add_argument("--slurm", action="store_true", help="submit to Slurm instead")
    slurm.add_argument(
        "--executor",
        choices=("slurm", "local", "debug"),
        help="submitit executor (--slurm: slurm; local/debug run on this machine, for tests)",
    )
    slurm.add_argument("--partition", help="Slurm partition")
    slurm.add_argument("--time", type=int, default=24 * 60, help="minutes per run (default 1440)")
    slurm.add_argument("--gpus-per-run", type=int, default=0, help="GPUs per run (default 0)")
    slurm.add_argument("--mem-gb", type=float, help="memory per run")
    slurm.add_argument("--account", help="Slurm account")
    slurm.add_argument("--qos", help="Slurm QOS")
    slurm.add_argument("--constraint", help="Slurm constraint")
    slurm.add_argument(
        "--array-parallelism", type=int, default=64, help="array tasks at a time (default 64)"
    )
    slurm.add_argument(
        "--signal-delay",
        type=int,
        default=90,
        metavar="SECONDS",
        help="Slurm warns a run this long before its time limit; it checkpoints and requeues "
        "itself (default 90)",
    )
    slurm.add_argument("--no-wait", action="store_true", help="submit and return")


def _split_items(items: list[str]) -> tuple[list[str], list[str]]:
    recipes, overrides = [], []
    for it in items:
        (overrides if "=" in it else recipes).append(it)
    return recipes, overrides


def _parse_items(args: argparse.Namespace) -> None:
    """Options mixed in with the recipes and overrides (argparse stops at the first positional
    otherwise): parse what came after it, keeping what was parsed before."""
    inner = argparse.ArgumentParser(prog="gcnt sweep")
    _options(inner)
    inner.add_argument("items", nargs="*")
    rest = list(args.items)
    del args.items
    inner.parse_intermixed_args(rest, namespace=args)


def run(args: argparse.Namespace) -> int:
    _parse_items(args)
    if not args.items:
        log.error("give recipe files or a sweep directory (see gcnt sweep --help)")
        return 2
    from gcnt.recipes import RecipeError, find_recipe
    from gcnt.sweep import (
        ACTIVE,
        MANIFEST,
        ClusterOptions,
        Manifest,
        SweepError,
        SweepLock,
        default_dir,
        default_jobs,
        expand,
        now,
        run_local,
        run_submitit,
    )

    if args.slurm or args.executor:  # before the sweep directory is written
        from gcnt.extras import require

        require("submitit", f"gcnt sweep --executor {args.executor or 'slurm'}")
    recipes, overrides = _split_items(args.items)
    try:
        if len(recipes) == 1 and Path(recipes[0]).is_dir():
            sweep_dir = Path(recipes[0])
            if overrides or args.methods or args.seeds or args.per_robot:
                raise SweepError(
                    f"{sweep_dir}: a sweep directory is continued as it was set up; give recipes "
                    "to add runs (overrides, --methods, --seeds and --per-robot apply to new runs "
                    "only)"
                )
            manifest = Manifest.load(sweep_dir)
            if args.eval:
                for r in manifest.runs:
                    r.evals = list(dict.fromkeys([*r.evals, *args.eval]))
                    r.eval_episodes = args.episodes
                    r.eval_deterministic = args.eval_deterministic
        else:
            try:  # a recipe file, or one that ships with gcnt by name
                recipes = [str(find_recipe(r)) for r in recipes]
            except RecipeError as e:
                raise SweepError(str(e)) from None
            bad = [r for r in recipes if not Path(r).is_file()]
            if bad:
                raise SweepError(f"no such recipe file: {', '.join(bad)}")
            if not recipes:
                raise SweepError("give at least one recipe file (or a sweep directory)")
            if args.dir is None:
                args.dir = default_dir(recipes, overrides, args.per_robot)
            sweep_dir = args.dir
            specs = expand(
                recipes,
                sweep_dir,
                methods=args.methods,
                seeds=args.seeds,
                overrides=overrides,
                evals=args.eval,
                eval_episodes=args.episodes,
                eval_deterministic=args.eval_deterministic,
                group=args.group,
                per_robot=args.per_robot,
            )
            if (sweep_dir / MANIFEST).is_file():
                manifest = Manifest.load(sweep_dir)
                manifest.merge(specs)
            else:
                manifest = Manifest(
                    sweep_dir, specs, {"created": now(), "command": ["gcnt", *sys.argv[2:]]}
                )
        if args.status:
            # a pool sweep being driven keeps its manifest current (a run is "running" from its
            # start, "done" once its last step ended); otherwise the states are worked out
            driven = manifest.executor == "pool" and SweepLock(manifest.dir).driver() is not None
            if not driven:
                manifest.refresh()
            print(manifest.table())
            return 0
        manifest.refresh()
        manifest.save()
        if args.dry_run:
            print(manifest.table())
            print(f"manifest: {manifest.path} (dry run: nothing started)")
            return 0
        t0 = time.monotonic()
        with SweepLock(manifest.dir):
            manifest.record_session()  # the code and command now running the sweep
            manifest.save()

            def report(spec) -> None:
                evals = ", ".join(f"eval {k}: {v}" for k, v in spec.eval_state.items())
                job = f" (job {spec.job_id})" if spec.job_id and spec.state in ACTIVE else ""
                print(
                    f"{now()}  {spec.id}: {spec.state}{job}{'; ' + evals if evals else ''}",
                    flush=True,
                )

            stored = manifest.meta.get("cluster") or {}
            if args.slurm or args.executor:
                opts = ClusterOptions(
                    executor=args.executor or "slurm",
                    partition=args.partition,
                    time_min=args.time,
                    cpus_per_run=args.cpus_per_run,
                    gpus_per_run=args.gpus_per_run,
                    mem_gb=args.mem_gb,
                    array_parallelism=args.array_parallelism,
                    account=args.account,
                    qos=args.qos,
                    constraint=args.constraint,
                    signal_delay_s=args.signal_delay,
                )
            elif stored.get("executor", "pool") != "pool":  # continued on its own cluster
                opts = ClusterOptions.from_dict(stored)
                print(f"sweep {manifest.dir}: on {opts.executor}, as submitted before", flush=True)
            else:
                opts = None
            if opts is not None and args.stack_seeds:
                raise SweepError(
                    "--stack-seeds runs in the local pool; on a cluster each run is a job of "
                    "its own"
                )
            if opts is not None:
                run_submitit(manifest, opts, wait=not args.no_wait, on_change=report)
                if args.no_wait:
                    print(manifest.table())
                    print(f"manifest: {manifest.path} (submitted; gcnt sweep {manifest.dir} "
                          "--status shows the states)")  # fmt: skip
                    return 0
            else:
                jobs = args.jobs or default_jobs(args.cpus_per_run)
                todo = sum(1 for r in manifest.runs if not r.complete())
                print(
                    f"sweep {manifest.dir}: {len(manifest.runs)} runs, {todo} to do, "
                    f"{jobs} at a time x {args.cpus_per_run} core(s)",
                    flush=True,
                )
                manifest.meta["cluster"] = {"executor": "pool", "cpus_per_run": args.cpus_per_run}
                run_local(
                    manifest,
                    jobs=jobs,
                    cpus_per_run=args.cpus_per_run,
                    on_change=report,
                    stack_seeds=args.stack_seeds,
                )
    except SweepError as e:
        print(f"gcnt sweep: error: {' '.join(str(e).split())}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:
        how = str(e) or "interrupted"
        print(f"{how}; run the same command again to resume", file=sys.stderr)
        return 143 if "SIGTERM" in how else 130
    manifest.refresh()
    manifest.save()
    print(manifest.table())
    counts = manifest.counts()
    print(
        f"manifest: {manifest.path}  ({', '.join(f'{v} {k}' for k, v in sorted(counts.items()))}; "
        f"{time.monotonic() - t0:.0f} s)"
    )
    failed = [r for r in manifest.runs if r.state == "failed" or "failed" in r.eval_state.values()]
    for r in failed:
        print(f"failed: {r.id} (log: {r.log})", file=sys.stderr)
    cancelled = [r for r in manifest.runs if r.state == "cancelled"]
    for r in cancelled:
        print(f"cancelled: {r.id} (run the sweep again to continue it)", file=sys.stderr)
    return 1 if failed or cancelled else 0
