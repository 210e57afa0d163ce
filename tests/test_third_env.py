"""A third env runs through the whole pipeline from its own package and its own recipe: the point env of
``tests/point_env.py`` registers itself and its instruction format (as an env package's ``__init__`` would), a recipe
registered here says what the experiments need, and nothing in envs/, talar_jax/ or experiments/ names it."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax.numpy as jnp
import pytest

from experiments.config import default_config
from experiments.pipeline import run
from experiments.recipes import _RECIPES, EnvRecipe, get_recipe, register_recipe
from tests.conftest import TINY_BERT
from tests.point_env import GOALS, MOVES


def _greedy_move(state, rng):
    """The move that brings the point closest to its goal (the scripted task-dataset collector)."""
    goal = jnp.asarray(GOALS)[state.task.goal]
    after = state.obs[:2] + 0.1 * jnp.asarray(MOVES)
    return jnp.argmin(jnp.linalg.norm(after - goal, axis=1)).astype(jnp.int32)


@pytest.fixture
def point_recipe(point_env_registered):
    clevr = get_recipe("clevr")
    recipe = EnvRecipe(
        env="point",
        goal_names=lambda: ["top right", "top left", "bottom left", "bottom right"],
        scripted_collector=lambda: ({}, _greedy_move, {"greedy": 1.0}),
        oracle_env_steps=10_000,
        oracle_target_success=0.9,
        num_tuples=2_000,
        talar=dataclasses.replace(clevr.talar, receiver_prefix_dims=None, translator_paraphrases=0),
        ifp=clevr.ifp,
        per_goal_report=True,
    )
    register_recipe(recipe)
    yield recipe
    _RECIPES.pop("point")


def test_a_third_env_runs_the_quick_pipeline_from_its_package_and_recipe(point_recipe, tmp_path):
    config = default_config(
        "point", quick=True, seeds=1, encoder=TINY_BERT, progress=False, deployment_strip=False, out=tmp_path
    )
    summary = run(config)
    assert summary["env"] == "point" and len(summary["final_success"]["train"]) == 1
    assert "| top right |" in (Path(tmp_path) / "talar" / "results.md").read_text()
