"""One registered recipe per env: everything the experiments need to know of an env, in one place.

A recipe names the env (``envs.make``), its goals, its scripted task-dataset collector, the oracle's budgets and
the experiment defaults of the referential game, translator and IFP. The pipeline, the oracle and the
comparison commands read recipes only; adding a third env means an env package (``envs/``, registering the env and,
with ``envs.register_instruction_format``, how its instruction file is read) and, here, one ``register_recipe`` call.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from talar_jax.ppo import PPOConfig
from talar_jax.talar import TalarConfig

# Referential-game settings of the experiment commands. Table 2's LR 3e-4 at Gumbel temperature 1 left the generator
# transmitting almost nothing in our runs (CLEVR, 6k steps: deterministic TL decoded the tuple's goal for 3 % of
# tuples, RG loss 0.54 = the loss of a receiver that ignores L_T); LR 3e-3 and temperature 2, 20k steps: 47 %, loss
# 0.36, against 0.18 for a receiver told the goal. The straight-through forward pass is the hard argmax whatever the
# temperature, which only softens the backward pass: temperature 4 (20k steps, 5 seeds) lowered the RG loss to 0.35
# and raised the translated table's distinct goal codes from 0.32 to 0.70 and its goal decodability from about 0.5
# to 0.83 (training instructions) and 0.33 to 0.52 (test); temperature 1: 0.41, 0.13 and 0.34 (3 seeds).
# Measured with scripts/probe_referential_game.py and runs/clevr-t4 (issue-6 notes).
# Eq. 2's expectation over T_i taken over every token of the tuple's instruction (rg_all_tokens) instead of one
# sampled token: CLEVR, 2 probe seeds, 20k steps, batch 64: the generator's TL decodes the tuple's goal for 63-71 %
# of tuples (one token, batch 256: 37-52 %, 5 seeds), RG loss 0.30 (0.35), translated table: distinct goal codes
# 0.95-1.0, goal decodability 0.98-1.0 train / 0.74-0.80 test. Batch 256 with all tokens did better still (0.79-0.84
# of tuples, RG loss 0.25) but costs 3.7x the time on a 2-core CPU. With it, 2M IFP steps, 5 seeds: 96.8 / 84.0 %
# success on train / test instructions (results/clevr-talar-alltokens-5seeds-2M); with ExperimentConfig's default
# sentence readout as well: 97.8 / 92.2 % (results/clevr-talar-5seeds-2M-final).
EXPERIMENT_TALAR = TalarConfig(rg_learning_rate=3e-3, gumbel_temperature=4.0, rg_all_tokens=True, rg_batch_size=64)

# The IFP's PPO in the experiment commands: Table 2 (PPOConfig's defaults) with the original's evaluation
# (stochastic episodes; a deterministic discrete policy can repeat a blocked push until the time limit).
EXPERIMENT_IFP = PPOConfig(eval_every_chunks=2, eval_episodes=80, eval_deterministic=False)


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


# The receiver reads the prefix embeddings' first 32 principal components (TalarConfig.receiver_prefix_dims), which
# makes a referential-game step 2.7x cheaper on CLEVR (54 against 148 ms for 5 seeds, one process, 2-core CPU) at no
# loss of TL quality: 20k steps, 5 seeds, translator 3k steps, distinct goal codes 0.928, decodable 0.961 train /
# 0.824 test (results/supervised-budget/README.md), against 0.857, 0.927 / 0.820 for the whole 384-entry embedding in
# results/clevr-talar-5seeds-2M-session11. Not on the kitchen, where 32 components keep 86 % of the prefixes'
# variance (CLEVR: 97 %) and cost one seed in five a merged sub-task code.
# The pipeline on it (results/clevr-talar-5seeds-2M-d32, same task dataset and seeds as session 11's run): distinct
# goal codes 0.948, decodable 0.972 / 0.881, against 0.857, 0.927 / 0.820. Each step also reads at most 8 of a tuple's
# tokens (TalarConfig.rg_token_slots; CLEVR instructions have 12.6 on average, up to 17): 13.4 against 22.7 ms per
# step for 5 seeds (one process), and at 20k steps, translator 3k, distinct goal codes 0.95, decodable 0.97 / 0.829
# against 0.928, 0.961 / 0.824 with every slot (results/supervised-budget/README.md).
# The translator: 2k Adam steps at LR 2e-3 instead of Table 2's 10k at 3e-4 (5x cheaper), learning also from 8
# paraphrases per training instruction (TalarConfig.translator_paraphrases; issue 22). On one game (runs/clevr-2M-slots,
# paired, 5 seeds; results/supervised-budget/README.md) the short, faster translator generalises better, not worse:
# test-matches-train 0.757 (10k @ 3e-4) -> 0.859 (2k @ 2e-3) -> 0.945 (2k @ 2e-3 with paraphrases), decodable test
# 0.753 -> 0.839 -> 0.905, agreement on our development phrasings 46.2 -> 51.6 -> 64.5 %; on a second game (other
# seeds, no paraphrases) 0.928 test-matches-train against 0.875 for 10k @ 3e-4, decodable test 0.905 against 0.870.
# Behaviour cloning of the pre-trained BERT-* baselines keeps its former budget (10k steps at 3e-4).
# The translator reads every word piece's state through attention pooling (translator_tokens) and learns from
# paraphrases that may also front the closing phrase ("Behind the blue ball, push the red ball."): measured on the
# paper's budget (2M x 5, results/unseen-phrasings.md), against the same recipe with the one-vector readout and no
# fronting: TL agreement on our development phrasings 64.5 -> 87.8 %, success 77.6 -> 90.9 %; test set agreement
# 94.5 -> 97.3 %, success 96.0 -> 97.3 %. Fronting without the token readout lifted development agreement to 73.6 %
# but cost the test set 1.4 points. The translator stage costs about 4x more (272 s vs 70 s on 2 cores).
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
# The kitchen's six sub-tasks need a quarter of the referential game and a fifth of the translator steps, measured
# with `python scripts/supervised_budget.py runs/kitchen-4M/oracle/dataset --env kitchen --seeds 5 --rg-milestones
# 2000 5000 --translator-steps 500 2000 10000` (results/supervised-budget/): at 5k RG steps every seed's translated TL
# gives the six sub-tasks six distinct codes (distinct_goal_codes 1.0, decodable 1.0 train / 0.997 test; translator
# 2k steps = 10k steps); at 2k RG steps 0.867; the 20k-step run of results/kitchen-talar-5seeds-4M (other seeds): 0.933.
# Each step reads at most 16 of a tuple's tokens (TalarConfig.rg_token_slots; kitchen instructions have 13.7 tokens on
# average and up to 25, so about 45 % of the all-token layout's receiver rows were padding): 1.1-1.6x cheaper steps
# for 5 seeds (four timings on this noisy 2-core CPU, each in one process), and at 5k steps the same TL (distinct goal
# codes 1.0, decodable 1.0 / 1.0; results/supervised-budget/README.md).
# The translator reads token states and learns from 8 paraphrases per training instruction that may put an unknown
# word in place of a function word (as CLEVR's; issue 22). Measured at 4M x 5 on one game and one policy (the policy is
# bit-identical: every goal keeps its training code), episodes paired as `experiments.generalize` pairs them
# (results/unseen-phrasings.md, results/kitchen-talar-5seeds-4M-tokens): success on our development phrasings 85.5 ->
# 89.1 %, TL agreement 91.3 -> 94.0 %; the test set unchanged (agreement 100 %, success 96.3 %). Fronted phrases stay
# off (not measured on the kitchen). The translator stage costs 165 s for 5 seeds instead of
# about 60 s on 2 cores.
KITCHEN_TALAR = dataclasses.replace(
    EXPERIMENT_TALAR,
    rg_steps=5_000,
    translator_steps=2_000,
    rg_token_slots=16,
    translator_paraphrases=8,
    paraphrase_unknown_words=True,
    translator_tokens=True,
)
# The posture term's targets: the scripted controller's postures at success instead of TALAR's hard-coded ones
# (README, "Kitchen reward"; the measurements are in the KitchenConfig docstring and results/).
KITCHEN_ENV_OPTIONS = {"posture_targets": "scripted"}

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
    )
)
