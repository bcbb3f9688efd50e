"""Tests for the ``compile:`` switches of ``gcnt.rl.accelerate``, without compiling anything: the
switches are accepted from a recipe (off by default, but compile: auto), the CUDA-only ones are rejected on a CPU
with a one-line reason, an unknown mode is refused, and the collector and optimiser keyword
arguments follow the configuration (``accelerate`` leaves a function alone when nothing is
switched on). Compiling itself is tested in tests/test_accelerate.py.
"""

from pathlib import Path

import pytest

from gcnt.recipes import RecipeError, load_recipe

ROOT = Path(__file__).parents[1]
QUICK = ROOT / "recipes/quickstart.yaml"


def test_compile_switches_are_accepted_and_cuda_only_ones_rejected_on_cpu():
    r = load_recipe(
        QUICK, ["compile.compile=true", "compile.policy_compile=true", "compile.mode=default"]
    )
    assert r.compile.compile and r.compile.policy_compile
    assert load_recipe(QUICK).compile.compile == "auto"  # chosen per run: test_compile_choice
    for key in ("cudagraphs", "amp", "replay_on_device", "policy_cudagraphs"):
        with pytest.raises(RecipeError) as e:
            load_recipe(QUICK, [f"compile.{key}=true"])
        msg = str(e.value)
        assert f"compile.{key}=true needs a CUDA device" in msg and "\n" not in msg
    with pytest.raises(RecipeError, match="compile: mode must be one of"):
        load_recipe(QUICK, ["compile.mode=fast"])


def test_collector_and_optimizer_switches():
    from gcnt.recipes import CompileConfig
    from gcnt.rl.accelerate import accelerate, collector_kwargs, optimizer_kwargs

    assert collector_kwargs(CompileConfig()) == {}
    assert collector_kwargs(CompileConfig(policy_compile=True)) == {"compile_policy": True}
    assert optimizer_kwargs(CompileConfig(), "cpu") == {"fused": True}
    f = lambda x: x + 1  # noqa: E731
    assert accelerate(f, CompileConfig(), "cpu") is f
