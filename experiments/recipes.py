"""One registered recipe per env: everything the experiments need to know of an env, in one place.

A recipe names the env (``envs.make``), its goals, its scripted task-dataset collector, the oracle's budgets,
the experiment defaults of the referential game, translator and IFP, and its hierarchical RL set-up (if any). The
pipeline, the oracle, the comparison commands and ``experiments.hrl`` read recipes only; adding a third env means an
env package (``envs/``, registering the env and, with ``envs.register_instruction_format``, how its instruction file
is read) and, here, one ``register_recipe`` call.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from talar_jax.ppo import PPOConfig
from talar_jax.talar import TalarConfig

# The referential game of both envs: LR 3e-3 and Gumbel temperature 4 (at Table 2's 3e-4 and 1 the generator carried
# almost no goal information) and Eq. 2's expectation over every token of the instruction, 64 tuples per step.
# Measurements: results/recipe-measurements.md.
EXPERIMENT_TALAR = TalarConfig(rg_learning_rate=3e-3, gumbel_temperature=4.0, rg_all_tokens=True, rg_batch_size=64)

# The IFP's PPO in the experiment commands: Table 2 (PPOConfig's defaults) with the original's evaluation
# (stochastic episodes; a deterministic discrete policy can repeat a blocked push until the time limit). The
# learning curve's evaluations are small (24 episodes per seed and split, every 4 chunks) and the reported one after
# the last chunk dense (200). At 80 episodes every 2 chunks, evaluation was 29 % of the kitchen's policy stage; at
# 24 every 2 chunks, 12 %. The final evaluation's keys depend on the chunk alone, so the curve's schedule changes
# neither what is trained nor what is reported.
EXPERIMENT_IFP = PPOConfig(eval_every_chunks=4, eval_episodes=24, final_eval_episodes=200, eval_deterministic=False)


@dataclasses.dataclass(frozen=True)
class HRLRecipe:
    """An env's hierarchical RL set-up (``experiments.hrl``, paper Fig. 6).

    Attributes:
        low_env: the ``envs.make`` name of the long-horizon env the low-level policy acts in.
        episode_length: high-level steps per episode (each held for ``--hold`` low-level steps).
        env_steps: low-level env steps per seed and method.
        low_env_options: ``envs.make`` options of ``low_env``.
        args_options: ``HRLArgs`` fields passed to ``low_env`` as the ``envs.make`` option of the same name (CLEVR's
            ``arrangement_reward``); the summary records them.
    """

    low_env: str
    episode_length: int
    env_steps: int
    low_env_options: dict[str, Any] = dataclasses.field(default_factory=dict)
    args_options: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class EnvRecipe:
    """What the experiments need of one env.

    Attributes:
        env: the ``envs.make`` name.
        goal_names: () -> one name per goal id (figures and per-goal tables).
        scripted_collector: () -> (env options, ``act(state, rng) -> action``, its settings) of the scripted
            task-dataset collector, or None when the env has none (the oracle then trains a PPO policy).
        oracle_env_steps: the PPO oracle's budget (training stops at ``oracle_target_success``).
        oracle_target_success: the oracle's success target on training instructions.
        num_tuples: task-dataset size.
        talar: referential game and translator defaults of the experiment commands.
        ifp: the instruction-following policy's PPO defaults (the budget included).
        env_options: ``envs.make`` options of the IFP's env.
        showcase_goals: () -> goal ids the report's deployment strip shows one episode of (None: every goal).
        train_patterns: the number of training sentence patterns (``--num-patterns`` picks the first k: paper
            Table 3); None for an env whose instructions are not built from patterns.
        per_goal_report: whether the run report tabulates success per goal (a handful of sub-tasks; CLEVR's 80
            goals stay in summary.json).
        paper_margin: TALAR's lead over the best baseline in the paper's Fig. 4, points of success (None: not in
            the paper).
        hrl: the hierarchical RL set-up of ``experiments.hrl`` (None: the env has none).
    """

    env: str
    goal_names: Callable[[], list[str]]
    scripted_collector: Callable[[], tuple[dict[str, Any], Callable[..., Any], dict[str, float]]] | None
    oracle_env_steps: int
    oracle_target_success: float
    num_tuples: int
    talar: TalarConfig
    ifp: PPOConfig
    env_options: dict[str, str] = dataclasses.field(default_factory=dict)
    showcase_goals: Callable[[], list[int]] | None = None
    train_patterns: int | None = None
    per_goal_report: bool = False
    paper_margin: float | None = None
    hrl: HRLRecipe | None = None

    @property
    def default_collector(self) -> str:
        return "policy" if self.scripted_collector is None else "scripted"


_RECIPES: dict[str, EnvRecipe] = {}


def register_recipe(recipe: EnvRecipe) -> EnvRecipe:
    """Adds (or replaces) the recipe of ``recipe.env``."""
    _RECIPES[recipe.env] = recipe
    return recipe


def recipe_names() -> tuple[str, ...]:
    return tuple(_RECIPES)


def get_recipe(env: str) -> EnvRecipe:
    """The recipe of an env, or one clear error naming the envs that have one."""
    if env not in _RECIPES:
        raise ValueError(f"unknown experiment env {env!r}; valid: {', '.join(_RECIPES)}")
    return _RECIPES[env]


# ------------------------------------------------------------------------------------------------
# CLEVR-Robot
# ------------------------------------------------------------------------------------------------
CLEVR_SCRIPTED_EPSILON = 0.2  # random-direction probability of the scripted CLEVR collector


def _clevr_goal_names() -> list[str]:
    from envs.clevr.tasks import NUM_GOALS, describe_goal

    return [describe_goal(goal) for goal in range(NUM_GOALS)]


def _clevr_collector():
    """Greedy pushes of the goal's source ball with epsilon-random directions, in the original's ``collect``
    action space (8 pushes of the source ball), so s_i -> s_T shows which ball the instruction names."""
    from envs.clevr.scripted import greedy_push

    def act(state, rng):
        return greedy_push(state, rng, CLEVR_SCRIPTED_EPSILON)

    return {"action_type": "collect"}, act, {"epsilon": CLEVR_SCRIPTED_EPSILON}


def _clevr_showcase_goals() -> list[int]:
    """The first goal of each relation (front, behind, left, right)."""
    from envs.clevr.tasks import GOAL_RELATION, NUM_RELATIONS

    return [int(list(GOAL_RELATION).index(relation)) for relation in range(NUM_RELATIONS)]


# CLEVR: a cheaper referential game (32 principal components of the prefix embeddings, 8 token slots per step) at
# no loss of TL quality, and a shorter translator that reads token states and learns from paraphrases, which
# generalises better to unseen phrasings (results/recipe-measurements.md).
CLEVR_TALAR = dataclasses.replace(
    EXPERIMENT_TALAR,
    receiver_prefix_dims=32,
    rg_token_slots=8,
    translator_steps=2_000,
    translator_learning_rate=2e-3,
    translator_paraphrases=8,
    paraphrase_front_phrases=True,
    paraphrase_unknown_words=True,
    translator_tokens=True,
    behaviour_cloning_steps=10_000,
    behaviour_cloning_learning_rate=3e-4,
)

register_recipe(
    EnvRecipe(
        env="clevr",
        goal_names=_clevr_goal_names,
        scripted_collector=_clevr_collector,
        oracle_env_steps=3_000_000,
        oracle_target_success=0.9,
        num_tuples=100_000,
        talar=CLEVR_TALAR,
        ifp=dataclasses.replace(EXPERIMENT_IFP, total_env_steps=2_000_000),
        showcase_goals=_clevr_showcase_goals,
        train_patterns=9,
        paper_margin=13.4,
        hrl=HRLRecipe(
            "clevr-arrangement", episode_length=10, env_steps=1_000_000, args_options=("arrangement_reward",)
        ),
    )
)

# ------------------------------------------------------------------------------------------------
# FrankaKitchen
# ------------------------------------------------------------------------------------------------
KITCHEN_SCRIPTED_NOISE = 0.1  # std of the Gaussian action noise of the scripted kitchen collector


def _kitchen_goal_names() -> list[str]:
    from envs.kitchen.tasks import TASK_NAMES

    return list(TASK_NAMES)


def _kitchen_collector():
    """The IK-waypoint controller of ``envs/kitchen/scripted.py`` with Gaussian action noise (all six sub-tasks;
    the PPO oracle here never learned the microwave)."""
    from envs.kitchen.scripted import noisy_scripted_action

    def act(state, rng):
        return noisy_scripted_action(state, rng, KITCHEN_SCRIPTED_NOISE)

    return {}, act, {"noise": KITCHEN_SCRIPTED_NOISE}


KITCHEN_IFP = dataclasses.replace(EXPERIMENT_IFP, total_env_steps=4_000_000)
# The kitchen's six sub-tasks need a quarter of the referential game and a fifth of the translator steps for the
# same TL (six distinct codes on every seed); the translator reads token states and learns from paraphrases with
# unknown words, as CLEVR's (results/recipe-measurements.md).
KITCHEN_TALAR = dataclasses.replace(
    EXPERIMENT_TALAR,
    rg_steps=5_000,
    translator_steps=2_000,
    rg_token_slots=16,
    translator_paraphrases=8,
    paraphrase_unknown_words=True,
    translator_tokens=True,
)
# The posture term: the scripted controller's postures at success instead of TALAR's hard-coded ones, the
# microwave's at the closed door's handle, and a stillness test on the noise-free distance (results/kitchen-seeds/:
# 8 of 8 probe seeds open the microwave against 3 of 8); docs/kitchen-reward.md.
KITCHEN_ENV_OPTIONS = {"posture_targets": "grasp", "stillness": "true"}

register_recipe(
    EnvRecipe(
        env="kitchen",
        goal_names=_kitchen_goal_names,
        scripted_collector=_kitchen_collector,
        oracle_env_steps=10_000_000,
        oracle_target_success=0.7,
        num_tuples=50_000,
        talar=KITCHEN_TALAR,
        ifp=KITCHEN_IFP,
        env_options=KITCHEN_ENV_OPTIONS,
        per_goal_report=True,
        paper_margin=63.2,
        hrl=HRLRecipe(
            "kitchen-all", episode_length=28, env_steps=1_000_000, low_env_options={"all_tasks_reward": "count"}
        ),
    )
)
