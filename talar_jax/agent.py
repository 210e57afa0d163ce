"""A trained instruction follower, loaded from a finished experiment run: give it any sentence and let it act.

``agent = talar_jax.agent.load("runs/kitchen", seed=0)`` reads a run folder of ``experiments.clevr`` /
``experiments.kitchen`` (the run root or its method folder, e.g. ``runs/kitchen/talar``):

- ``config.json``: the resolved experiment config (env, env options, method, encoder, sentence readout, TL shape);
- ``language.json``: the encoder's name and weights sha256 and the language cache key the run trained with;
- ``<method>/translator/params.msgpack`` (TALAR, Handcrafted, GLA): the seed-stacked translators (end-to-end TALAR:
  the ``translator`` entry of ``end-to-end/joint/params.msgpack``);
- ``ifp/ppo/checkpoints``: the policy (and, for BERT-* and aligned BERT-*, the instruction encoding layer) after the
  last chunk.

Then ``agent.encode(sentences)`` gives the features the translator reads, ``agent.translate(sentences)`` the
language codes the policy is conditioned on (the TL for TALAR), ``agent.nearest_goal(code)`` the goal whose
training instructions share that code, ``agent.act(obs, code, rng)`` an action and ``agent.rollout(sentence, rng)``
a whole episode. One-hot runs cannot read a sentence they were not trained with and raise ``AgentError``.
"""

from __future__ import annotations

import dataclasses
import json
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import envs
from talar_jax.baselines import AlignedEncodingLayer, NLEncodingLayer
from talar_jax.checkpoint import load_tree
from talar_jax.language import TOKEN_READOUT, build_cache, load_encoder, readout_features, sentence_features
from talar_jax.networks import make_inference_fn, make_ppo_networks
from talar_jax.report import LANGUAGE_RECORD
from talar_jax.talar import TalarConfig, make_translate
from talar_jax.task_language import TaskLanguageSpec

TRANSLATOR_STAGES = {
    "talar": "talar/translator",
    "handcrafted": "handcrafted/translator",
    "gla": "gla/translator",
    "end-to-end": "end-to-end/joint",  # the joint fit's parameters: {"generator", "receiver", "translator"}
}
ENCODING_LAYER_METHODS = (
    "bert-binary",
    "bert-continuous",
    "pretrained-bert-binary",
    "pretrained-bert-continuous",
    "aligned-bert-binary",  # the encoding layer has the TL generator's architecture (AlignedEncodingLayer)
    "aligned-bert-continuous",
)


class AgentError(ValueError):
    """A run folder, sentence or option an agent cannot use (one line, meant for the user)."""


@dataclasses.dataclass(frozen=True)
class Episode:
    """One episode of an agent: arrays over ``episode_length`` steps (steps after the episode ended are padding).

    Attributes:
        observations: (T, obs) the observation each action was chosen on.
        actions: (T, ...) the actions.
        qpos: (T + 1, nq) physics positions from the reset on (for rendering).
        valid: (T,) True for the steps of the episode (before and at its end).
        success: whether the episode's goal was reached.
        length: number of valid steps.
        goal: the goal id the episode was scored on.
    """

    observations: np.ndarray
    actions: np.ndarray
    qpos: np.ndarray
    valid: np.ndarray
    success: bool
    length: int
    goal: int


def find_method_folder(run_dir: str | Path) -> Path:
    """The method folder of a run: ``run_dir`` itself when it holds ``config.json``, else its only method subfolder
    holding one (TALAR's when there are several)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise AgentError(f"run folder {run_dir} does not exist")
    if (run_dir / "config.json").is_file() and (run_dir / "ifp").exists():
        return run_dir
    candidates = sorted(p.parent for p in run_dir.glob("*/config.json") if (p.parent / "ifp").exists())
    if not candidates:
        raise AgentError(f"{run_dir} holds no experiment run (no <method>/config.json with an ifp stage)")
    if len(candidates) > 1:
        talar = [c for c in candidates if c.name == "talar"]
        if not talar:
            names = ", ".join(str(c) for c in candidates)
            raise AgentError(f"{run_dir} holds several runs ({names}); pass one of them")
        return talar[0]
    return candidates[0]


def _latest_policy_params(ppo_dir: Path) -> dict[str, Any]:
    import orbax.checkpoint as ocp

    if not (ppo_dir / "checkpoints").is_dir():
        raise AgentError(f"{ppo_dir} has no policy checkpoints")
    manager = ocp.CheckpointManager((ppo_dir / "checkpoints").absolute())
    step = manager.latest_step()
    if step is None:
        raise AgentError(f"{ppo_dir} has no policy checkpoint")
    return manager.restore(step, args=ocp.args.StandardRestore())["params"]


class Agent:
    """One seed of a finished run: encoder, instruction encoding (translator or encoding layer), policy and env."""

    def __init__(self, run_dir: str | Path, seed: int = 0, physics: str | None = None, check_encoder: bool = True):
        folder = find_method_folder(run_dir)
        if not (folder / "ifp" / "stage.json").is_file():
            raise AgentError(
                f"the run in {folder} is not finished (its ifp stage has no stage.json): rerun its command to finish it"
            )
        self.folder = folder
        self.config = json.loads((folder / "config.json").read_text())
        self.method = self.config["method"]
        if self.method == "onehot":
            raise AgentError(
                "a One-hot run gives every training sentence its own code and has no way to read a new sentence; "
                "load a TALAR, end-to-end TALAR, Handcrafted, GLA or BERT-* run"
            )
        if self.method not in TRANSLATOR_STAGES and self.method not in ENCODING_LAYER_METHODS:
            raise AgentError(
                f"method {self.method!r} has no sentence encoding an agent can use; load a TALAR, end-to-end TALAR, "
                "Handcrafted, GLA or BERT-* run"
            )
        seeds = int(self.config["seeds"])
        if not 0 <= seed < seeds:
            raise AgentError(f"--seed must lie in 0..{seeds - 1} (the run has {seeds} seeds), got {seed}")
        self.seed = seed
        self.env_name = self.config["env"]
        reads_tokens = self.method in TRANSLATOR_STAGES and self.config["talar"].get("translator_tokens", False)
        self.readout = TOKEN_READOUT if reads_tokens else self.config["sentence_readout"]
        self.env = envs.make(
            self.env_name, physics=physics or envs.default_backend(), **(self.config.get("env_options") or {})
        )
        self.encoder = load_encoder(self.config.get("encoder"))
        self.cache = build_cache(self.env_name, self.encoder, progress=False)
        self._cache_features: np.ndarray | None = None
        if check_encoder:
            self._check_encoder()
        params = jax.tree.map(lambda x: np.asarray(x)[seed], _latest_policy_params(folder / "ifp" / "ppo"))
        self._encoding = self._make_encoding(params)
        train_rows = np.flatnonzero(self.cache.is_train)
        self._train_codes = np.asarray(self._encoding(self.cache_features()[train_rows]))
        self._train_goals = self.cache.goal_ids[train_rows]
        ifp = self.config["ifp"]
        self.code_size = int(self._train_codes.shape[1])
        networks = make_ppo_networks(
            self.env.observation_size, self.code_size, self.env.action_spec, tuple(ifp["hidden_sizes"])
        )
        self._policy_params = {k: v for k, v in params.items() if k != "conditioner"}
        self._make_policy = make_inference_fn(networks)
        self._episode = jax.jit(self._episode_fn, static_argnames=("deterministic",))

    # --- language --------------------------------------------------------------------------------------------
    def _check_encoder(self) -> None:
        record_path = self.folder / LANGUAGE_RECORD
        if not record_path.is_file():
            return  # runs made before the record existed: the encoder option in config.json is all there is
        record = json.loads(record_path.read_text())
        if record.get("weights_sha256") != self.encoder.weights_sha256 or record.get("cache_key") != self.cache.key:
            raise AgentError(
                f"the encoder found ({self.encoder.name}, weights sha256 {self.encoder.weights_sha256[:12]}) is not "
                f"the one the run trained with ({record.get('encoder_name')}, {str(record.get('weights_sha256'))[:12]})"
            )

    def _make_encoding(self, params: dict[str, Any]):
        if self.method in TRANSLATOR_STAGES:
            talar = self.config["talar"]
            if self.method in ("talar", "end-to-end"):
                spec = TaskLanguageSpec(**talar["spec"])
            elif self.method == "handcrafted":
                spec = TaskLanguageSpec(num_predicates=0, num_arguments=1, arg_size=self.cache.num_goals)
            else:
                spec = TaskLanguageSpec(num_predicates=TaskLanguageSpec(**talar["spec"]).size, num_arguments=0)
            translator_config = TalarConfig(
                translator_hidden=tuple(talar["translator_hidden"]), translator_tokens=self.readout == TOKEN_READOUT
            )
            translate = make_translate(translator_config, spec)
            stage = self.folder.parent / TRANSLATOR_STAGES[self.method] / "params.msgpack"
            translator = load_tree(stage)
            if self.method == "end-to-end":  # the joint fit stores generator, receiver and translator together
                translator = translator["translator"]
            translator = jax.tree.map(lambda x: np.asarray(x)[self.seed], translator)
            return jax.jit(lambda features: translate(translator, features))
        if self.method in ENCODING_LAYER_METHODS:
            talar, binary = self.config["talar"], "binary" in self.method
            spec = TaskLanguageSpec(**talar["spec"])
            if self.method.startswith("aligned-"):
                layer = AlignedEncodingLayer(spec, tuple(talar["generator_hidden"]), binary=binary)
            else:
                layer = NLEncodingLayer(spec.size, binary)
            layer_params = params["conditioner"]
            return jax.jit(lambda features: layer.apply(layer_params, features, None))
        raise AgentError(f"method {self.method!r} has no sentence encoding an agent can use")

    @property
    def continuous_codes(self) -> bool:
        """True for BERT-continuous encodings (codes compared by distance, not equality)."""
        return self.method.endswith("bert-continuous")

    def encode(self, sentences: str | Sequence[str]) -> np.ndarray:
        """(S, F) the features the run's translator (or encoding layer) reads of each sentence."""
        sentences = [sentences] if isinstance(sentences, str) else list(sentences)
        for sentence in sentences:
            if not sentence.strip():
                raise AgentError("a sentence is empty")
        rows = {sentence: row for row, sentence in enumerate(self.cache.sentences)}
        fresh = [sentence for sentence in dict.fromkeys(sentences) if sentence not in rows]
        try:
            computed = sentence_features(self.encoder, fresh, self.readout) if fresh else None
        except ValueError as error:
            raise AgentError(str(error)) from None
        # sentences of the instruction file: exactly the features the run's stages read (loaded at construction)
        cached = self.cache_features()
        fresh_rows = {sentence: index for index, sentence in enumerate(fresh)}
        return np.stack([cached[rows[s]] if s in rows else computed[fresh_rows[s]] for s in sentences]).astype(
            np.float32
        )

    def cache_features(self) -> np.ndarray:
        """The features ``encode`` gives, of every sentence of the env's instruction file (cache rows)."""
        if self._cache_features is None:
            self._cache_features = readout_features(self.cache, self.readout, self.encoder)
        return self._cache_features

    def translate(self, sentences: str | Sequence[str]) -> np.ndarray:
        """(S, code_size) the code the policy is conditioned on for each sentence (TALAR: its task language)."""
        return self.translate_features(self.encode(sentences))

    def translate_features(self, features: np.ndarray) -> np.ndarray:
        """(S, code_size) codes of sentences given by their features (``encode`` or the cache's)."""
        return np.asarray(self._encoding(jnp.asarray(features, jnp.float32)))

    def nearest_goal(self, code: np.ndarray) -> int | None:
        """The goal most training instructions with exactly this code have (None if no training instruction has it);
        for continuous codes, the goal of the nearest training instruction's code."""
        code = np.asarray(code, np.float32).reshape(-1)
        if self.continuous_codes:
            return int(self._train_goals[np.argmin(np.linalg.norm(self._train_codes - code, axis=1))])
        same = np.all(np.abs(self._train_codes - code) < 0.5, axis=1)
        if not same.any():
            return None
        return int(Counter(self._train_goals[same].tolist()).most_common(1)[0][0])

    @property
    def training_codes(self) -> np.ndarray:
        """(N, code_size) the code of every training instruction of the run (HAL's high-level action space)."""
        return self._train_codes.copy()

    def goal_code(self, goal: int) -> np.ndarray:
        """The code most of the goal's training instructions translate to."""
        rows, counts = np.unique(self._train_codes[self._train_goals == goal].round(3), axis=0, return_counts=True)
        return rows[np.argmax(counts)]

    # --- acting ----------------------------------------------------------------------------------------------
    def act(self, obs: jax.Array, code: jax.Array, rng: jax.Array, deterministic: bool = False) -> jax.Array:
        """An action for one observation (obs,) and code (code_size,) (pure JAX: jit / vmap it)."""
        policy = self._make_policy(self._policy_params, deterministic)
        return policy(jnp.asarray(obs, jnp.float32), jnp.asarray(code, jnp.float32), rng)

    def _episode_fn(self, rng: jax.Array, code: jax.Array, goal: jax.Array, deterministic: bool = False):
        rng_reset, rng_steps = jax.random.split(rng)
        state = self.env.reset(rng_reset, goal)

        def step(carry, rng_step):
            state, ended = carry
            action = self.act(state.obs, code, rng_step, deterministic)
            next_state = self.env.step(state, action)
            record = (state.obs, action, next_state.data.qpos, ~ended, next_state.metrics["success"] * (~ended))
            return (next_state, ended | (next_state.done > 0.5)), record

        keys = jax.random.split(rng_steps, self.env.episode_length)
        _, (obs, actions, qpos, valid, success) = jax.lax.scan(step, (state, jnp.bool_(False)), keys)
        qpos = jnp.concatenate([state.data.qpos[None], qpos])
        return obs, actions, qpos, valid, jnp.max(success) > 0.5

    def check_goal(self, goal: int) -> int:
        if not 0 <= int(goal) < self.env.num_goals:
            raise AgentError(f"--goal must lie in 0..{self.env.num_goals - 1} for {self.env_name}, got {goal}")
        return int(goal)

    def rollout(self, sentence: str, rng: jax.Array, goal: int | None = None, deterministic: bool = False) -> Episode:
        """One episode following ``sentence``, scored on ``goal`` (default: the goal its code decodes to)."""
        code = self.translate(sentence)[0]
        if goal is None:
            goal = self.nearest_goal(code)
            if goal is None:
                raise AgentError(f"the code of {sentence!r} is no training instruction's code; give the goal it means")
        goal = self.check_goal(goal)
        obs, actions, qpos, valid, success = jax.device_get(
            self._episode(rng, jnp.asarray(code), jnp.int32(goal), deterministic=deterministic)
        )
        return Episode(obs, actions, qpos, valid, bool(success), int(valid.sum()), goal)

    def episodes(
        self, codes: np.ndarray, goals: np.ndarray, rng: jax.Array, deterministic: bool = False
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One episode per (code, goal) row, all vmapped in one call: ``(observations (E, T, obs), valid (E, T),
        success (E,))`` (``Episode``'s fields, batched; steps after an episode ended are padding)."""
        keys = jax.random.split(rng, len(goals))

        def episode(key, code, goal):  # the outputs returned, not the actions and physics positions
            obs, _, _, valid, success = self._episode_fn(key, code, goal, deterministic)
            return obs, valid, success

        obs, valid, success = jax.device_get(
            jax.jit(jax.vmap(episode))(keys, jnp.asarray(codes, jnp.float32), jnp.asarray(goals, jnp.int32))
        )
        return np.asarray(obs), np.asarray(valid), np.asarray(success)

    def success_rate(
        self, codes: np.ndarray, goals: np.ndarray, rng: jax.Array, deterministic: bool = False
    ) -> np.ndarray:
        """(E,) success of one episode per (code, goal) row, all episodes vmapped in one call."""
        return self.episodes(codes, goals, rng, deterministic)[-1]


def load(run_dir: str | Path, seed: int = 0, physics: str | None = None) -> Agent:
    """The agent of seed ``seed`` of a finished run folder (see the module docstring)."""
    return Agent(run_dir, seed=seed, physics=physics)
