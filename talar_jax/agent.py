"""A trained instruction follower, loaded from a finished experiment run: give it any sentence and let it act.

``agent = talar_jax.agent.load("runs/kitchen", seed=0)`` reads a run folder of ``experiments.clevr`` /
``experiments.kitchen`` (the run root or its method folder, e.g. ``runs/kitchen/talar``):

- ``config.json``: the resolved experiment config (env, env options, seeds, encoder, policy sizes);
- ``encoding.json``: the run's instruction encoding (``talar_jax.encodings.EncodingArtifact``): its kind, the
  sentence readout it reads, its code size and network shapes, and where its seed-stacked parameters lie (a file
  under the run root, e.g. a translator's ``params.msgpack``, or an entry of the policy checkpoint);
- ``language.json``: the encoder's name and weights sha256 and the language cache key the run trained with;
- ``ifp/ppo/checkpoints``: the policy (and an encoding trained with it) after the last chunk.

The agent knows no methods: the encoding record says everything, and ``talar_jax.encodings.make_encoding`` builds
the ``features -> codes`` function of its kind (kinds can be added with ``register_encoding_kind``).

Then ``agent.encode(sentences)`` gives the features the encoding reads, ``agent.translate(sentences)`` the
language codes the policy is conditioned on (the TL for TALAR), ``agent.nearest_goal(code)`` the goal whose
training instructions share that code, ``agent.act(obs, code, rng)`` an action and ``agent.rollout(sentence, rng)``
a whole episode. ``agent.understand(sentence)`` says whether the agent should act on it at all: a
``talar_jax.confidence.Verdict`` (``"understood"`` and the goal, ``"ambiguous"`` and the likeliest goals, or ``"not
understood"``) with a confidence calibrated by the run's ``confidence.json`` (``python -m experiments.calibrate``; a
run without one uses ``default_calibration()``). Runs whose record says they cannot read a new sentence (kind
``"none"``, e.g. One-hot) raise ``AgentError`` with the record's reason.

This module is the loader: it alone reads a run folder's files (``read_config``, ``read_policy_params``,
``read_encoding_params``, ``read_calibration``). A file that is missing or damaged (truncated, not JSON, a checkpoint
that does not restore) raises one ``AgentError`` naming the file and the command that rebuilds it; nothing is written.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import sys
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import envs
from talar_jax.checkpoint import load_tree, read_json_record
from talar_jax.clauses import ClauseParserConfig, join_fragments, merge_repeated_tasks, parse_clauses
from talar_jax.confidence import NOT_UNDERSTOOD, Calibration, ConfidenceError, Plan, Understanding, Verdict
from talar_jax.confidence.polarity import (
    POSITIVE,
    UNKNOWN,
    PolarityConfig,
    judged_classes,
    polarity_probabilities,
    polarity_states,
)
from talar_jax.encodings import (
    ENCODING_FILE,
    POLICY_SOURCE,
    EncodingArtifact,
    EncodingError,
    build_encoding,
    one_seed_params,
    stored_encoding_params,
)
from talar_jax.language import (
    TOKEN_READOUT,
    BertEncoder,
    build_cache,
    features_with_cache,
    load_encoder,
    readout_features,
    sentence_features,
)
from talar_jax.language.polarity import CLASSES as POLARITY_CLASSES
from talar_jax.language.polarity import task_phrase
from talar_jax.networks import make_inference_fn, make_ppo_networks
from talar_jax.report import LANGUAGE_RECORD


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


SHIPPED_AGENTS_DIR = Path(__file__).parent / "agents"
"""Agents shipped with the package, one folder each (``experiments.ship`` writes them): a run folder cut down to one
seed, its policy in ``POLICY_FILE`` instead of orbax checkpoints, and ``SHIPPED_RECORD`` saying where it came from."""
POLICY_FILE = "policy.msgpack"
GENERATOR_FILE = "task_language/params.msgpack"
"""TALAR's TL generator (and receiver), seed-stacked, in a method folder: what ``Agent.task_language`` reads."""
SHIPPED_RECORD = "shipped.json"
CONFIG_FILE = "config.json"
CONFIDENCE_FILE = "confidence.json"
"""A run's confidence calibration, in its method folder (``python -m experiments.calibrate`` writes it)."""
POLARITY_STEM = "polarity"
"""The polarity classifier every agent reads (``talar_jax.confidence.polarity``), beside the shipped agents as
``polarity.msgpack`` and ``polarity.json`` (``python -m experiments.polarity`` writes both); it reads one encoder's
states (and may fine-tune its top layers), so the record names the encoder."""
POLARITY_PARAMS, POLARITY_RECORD = f"{POLARITY_STEM}.msgpack", f"{POLARITY_STEM}.json"
JOIN_BELOW = 0.9
"""A clause that names nothing is joined to its neighbour when the parser's probability of the cut between them is
under this (``talar_jax.clauses.join_fragments``)."""
CLAUSES_STEM = "clauses"
"""The clause parser every agent reads (``talar_jax.clauses``), beside the shipped agents as ``clauses.msgpack`` and
``clauses.json`` (``python -m experiments.clauses`` writes both), for one encoder as the polarity classifier."""
DEFAULT_CALIBRATION_FILE = SHIPPED_AGENTS_DIR / "default_confidence.json"
"""The calibration of runs that have none of their own: the one fit on the kitchen TALAR run at the paper's budget
(``python -m experiments.calibrate runs/kitchen``, ``results/abstention.md``). Its familiarity is that of
all-MiniLM-L6-v2, so it means little for another encoder: calibrate such a run."""


def shipped_agents() -> tuple[str, ...]:
    """Names of the agents shipped with the package (``load(name)``)."""
    if not SHIPPED_AGENTS_DIR.is_dir():
        return ()
    return tuple(sorted(p.name for p in SHIPPED_AGENTS_DIR.iterdir() if p.is_dir() and not p.name.startswith("_")))


def find_method_folder(run_dir: str | Path, prefer: str | None = None) -> Path:
    """The method folder of a run: ``run_dir`` itself when it holds ``config.json``, else its only method subfolder
    holding one; with several (e.g. a comparison's output), the one named ``prefer`` (e.g. ``"talar"``), else an
    ``AgentError`` listing them. A name of ``shipped_agents()`` that is no folder here names that shipped agent."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir() and str(run_dir) in shipped_agents():
        run_dir = SHIPPED_AGENTS_DIR / str(run_dir)
    if not run_dir.is_dir():
        shipped = ", ".join(shipped_agents()) or "none"
        raise AgentError(f"run folder {run_dir} does not exist and no shipped agent has its name (shipped: {shipped})")
    if (run_dir / CONFIG_FILE).is_file() and (run_dir / "ifp").exists():
        return run_dir
    if (run_dir / "ifp").exists():
        raise AgentError(f"{run_dir / CONFIG_FILE} is missing: {_rebuild_hint(run_dir)}")
    candidates = sorted(p.parent for p in run_dir.glob("*/config.json") if (p.parent / "ifp").exists())
    unconfigured = sorted(p.parent for p in run_dir.glob("*/ifp") if not (p.parent / CONFIG_FILE).is_file())
    if not candidates and len(unconfigured) == 1:
        raise AgentError(f"{unconfigured[0] / CONFIG_FILE} is missing: {_rebuild_hint(unconfigured[0])}")
    if not candidates:
        raise AgentError(f"{run_dir} holds no experiment run (no <method>/config.json with an ifp stage)")
    if len(candidates) > 1:
        preferred = [c for c in candidates if prefer is not None and c.name == prefer]
        if not preferred:
            names = ", ".join(str(c) for c in candidates)
            raise AgentError(f"{run_dir} holds several runs ({names}); pass one of them")
        return preferred[0]
    return candidates[0]


def read_encoding(folder: Path) -> EncodingArtifact:
    """The encoding record of a method folder; ``AgentError`` when it is missing or malformed."""
    if not (folder / ENCODING_FILE).is_file():
        raise AgentError(
            f"the run in {folder} predates the encoding record (no {ENCODING_FILE}): rerun its command to write it "
            "(every finished stage is reused)"
        )
    try:
        return EncodingArtifact.read(folder)
    except (EncodingError, UnicodeDecodeError) as error:
        raise AgentError(f"{error}: {_rebuild_hint(folder)}") from None


# --- reading a run folder ---------------------------------------------------------------------------------------
def _rebuild_hint(folder: Path, stage: Path | None = None) -> str:
    """What rebuilds a method folder's damaged or missing file: a shipped agent is restored from the package; a run's
    file is written again by the run's command (after removing the finished ``stage`` that holds it, since a
    finished stage is reused as it is)."""
    if (folder / SHIPPED_RECORD).is_file():
        name = folder.parent.name
        return (
            f"restore the shipped agent {name!r} (reinstall talar-jax, or in a clone git checkout -- "
            f"talar_jax/agents/{name}), or ship it again (python -m experiments.ship RUN --name {name})"
        )
    try:
        env = json.loads((folder / CONFIG_FILE).read_text())["env"]
    except (OSError, ValueError, KeyError, TypeError):
        env = "<env>"
    remove = f"remove {stage} and " if stage is not None else ""
    return (
        f"{remove}rerun the command that made the run (python -m experiments.{env} --out {folder.parent} with its "
        "options; its finished stages are reused)"
    )


def _damaged(path: Path, problem: str, folder: Path, stage: Path | None = None) -> AgentError:
    return AgentError(f"{path} is damaged ({problem}): {_rebuild_hint(folder, stage)}")


def read_config(folder: Path) -> dict[str, Any]:
    """The run's resolved config (``config.json`` of its method folder)."""
    path = folder / CONFIG_FILE
    try:
        config = json.loads(path.read_bytes())
    except FileNotFoundError:
        raise AgentError(f"{path} is missing: {_rebuild_hint(folder)}") from None
    except ValueError as error:  # truncated or not JSON (undecodable bytes included)
        raise _damaged(path, f"not valid JSON: {error}", folder) from None
    if not isinstance(config, dict) or not all(key in config for key in ("env", "seeds")):
        raise _damaged(path, "not a run config: no env or seeds", folder)
    return config


def _read_tree(path: Path, folder: Path, stage: Path) -> Any:
    """A msgpack tree of the run (``save_tree``'s files), or the ``AgentError`` naming it."""
    if not path.is_file():
        raise AgentError(f"{path} is missing: {_rebuild_hint(folder, stage)}")
    try:
        tree = load_tree(path)
    except ValueError as error:  # msgpack's errors for truncated or foreign bytes are all ValueErrors
        raise _damaged(path, f"msgpack: {error}", folder, stage) from None
    if not isinstance(tree, dict):
        raise _damaged(path, "not a tree of parameters", folder, stage)
    return tree


class _UnretrievedReadErrors(logging.Filter):
    """Drops asyncio's "exception was never retrieved" reports (see ``_quiet_failed_restore``)."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "exception was never retrieved" not in record.getMessage()


def _quiet_failed_restore() -> None:
    """When a damaged checkpoint's restore fails, the tensorstore reads still in flight finish afterwards: some call
    back into orbax's event loop, closed by then (Python reports an unraisable ``RuntimeError``), and some leave a
    failed future nobody reads (asyncio logs it when it is collected). Either prints a traceback after the one-line
    error, at random. Those two reports, and only those, are dropped; the restore's own error is raised as usual."""
    previous = sys.unraisablehook
    if getattr(previous, "drops_closed_loop_callbacks", False):
        return

    def hook(unraisable) -> None:
        error = unraisable.exc_value
        if not (isinstance(error, RuntimeError) and str(error) == "Event loop is closed"):
            previous(unraisable)

    hook.drops_closed_loop_callbacks = True
    sys.unraisablehook = hook
    logging.getLogger("asyncio").addFilter(_UnretrievedReadErrors())


def read_policy_params(folder: str | Path) -> dict[str, Any]:
    """The policy's seed-stacked parameters of a method folder: its last checkpoint (a shipped agent's
    ``POLICY_FILE``: the last checkpoint's parameters of one seed)."""
    import orbax.checkpoint as ocp

    folder = Path(folder)
    stage = folder / "ifp"
    ppo_dir = stage / "ppo"
    if (ppo_dir / POLICY_FILE).is_file():
        return _read_tree(ppo_dir / POLICY_FILE, folder, stage)
    checkpoints = ppo_dir / "checkpoints"
    if not checkpoints.is_dir() and (folder / SHIPPED_RECORD).is_file():
        raise AgentError(f"{ppo_dir / POLICY_FILE} is missing: {_rebuild_hint(folder, stage)}")
    if not checkpoints.is_dir():
        raise AgentError(f"{ppo_dir} has no policy checkpoints: {_rebuild_hint(folder, stage)}")
    _quiet_failed_restore()
    try:
        with ocp.CheckpointManager(checkpoints.absolute()) as manager:
            step = manager.latest_step()
            if step is None:
                raise AgentError(f"{checkpoints} holds no policy checkpoint: {_rebuild_hint(folder, stage)}")
            # The arrays are read here, not on first use, so that a damaged file is told now and in one line.
            return jax.device_get(manager.restore(step, args=ocp.args.StandardRestore())["params"])
    except AgentError:
        raise
    except Exception as error:  # orbax and tensorstore raise many types for a damaged checkpoint
        lines = str(error).strip().splitlines()
        problem = lines[0][:160] if lines else type(error).__name__
        raise AgentError(
            f"the policy checkpoint in {checkpoints} is damaged (it does not restore: {problem}): "
            f"{_rebuild_hint(folder, stage)}"
        ) from None


def read_encoding_params(folder: Path, artifact: EncodingArtifact, policy_params: dict[str, Any] | None = None) -> Any:
    """The encoding's parameters of every seed (leading axis), from the file or policy entry its record names
    (``policy_params``: the policy's, read from the run when needed and not given)."""
    source = artifact.params
    if source is not None and source.source == POLICY_SOURCE and policy_params is None:
        policy_params = read_policy_params(folder)
    path = folder.parent / source.path if source is not None and source.source != POLICY_SOURCE else None
    stage = path.parent if path is not None and path.parent != folder.parent else None
    try:
        tree, _ = stored_encoding_params(artifact, folder, policy_params)
    except EncodingError as error:
        hint = f": {_rebuild_hint(folder, stage)}" if path is not None and not path.is_file() else ""
        raise AgentError(f"{error}{hint}") from None
    except ValueError as error:  # msgpack's errors for a truncated or foreign parameters file are ValueErrors
        raise _damaged(path, f"msgpack: {error}", folder, stage) from None
    if not isinstance(tree, dict):
        raise _damaged(path or folder / "ifp", "not a tree of parameters", folder, stage)
    return jax.tree.map(np.asarray, tree)


def read_calibration(path: str | Path) -> Calibration:
    """The calibration in ``path`` (a ``confidence.json``, or a method folder holding one)."""
    path = Path(path)
    if path.is_dir():
        path = path / CONFIDENCE_FILE
    if not path.is_file():
        raise AgentError(f"no calibration at {path}")
    try:
        return read_json_record(path, Calibration.from_json, ConfidenceError)
    except (ConfidenceError, UnicodeDecodeError) as error:
        raise AgentError(f"{error}: calibrate the run again (python -m experiments.calibrate {path.parent})") from None


def default_calibration() -> Calibration:
    """The calibration of a run that has none (``DEFAULT_CALIBRATION_FILE``); its ``source["default"]`` is True so
    that callers can say so."""
    return Calibration.from_json(json.loads(DEFAULT_CALIBRATION_FILE.read_text()))


def _sentence_list(sentences: Any) -> Sequence[Any]:
    if not isinstance(sentences, Sequence):
        raise TypeError(f"sentences are a str or a sequence of them, got {type(sentences).__name__}: {sentences!r}")
    return sentences


class Agent:
    """One seed of a finished run: encoder, instruction encoding (as its ``encoding.json`` records it), policy and
    env.

    Attributes:
        folder: the run's method folder; config: its ``config.json``; method: the method it names (for display).
        encoding: the run's ``EncodingArtifact``; readout: the sentence readout the encoding reads; code_size: the
            size of its codes.
        seed, env, env_name, encoder, cache: the seed, env, sentence encoder and language cache of the run.
    """

    def __init__(self, run_dir: str | Path, seed: int = 0, physics: str | None = None, check_encoder: bool = True):
        folder = find_method_folder(run_dir)
        if not (folder / "ifp" / "stage.json").is_file():
            raise AgentError(
                f"the run in {folder} is not finished (its ifp stage has no stage.json): rerun its command to finish it"
            )
        self.folder = folder
        self.config = read_config(folder)
        self.method = str(self.config.get("method", folder.name))
        self.encoding = read_encoding(folder)
        if not self.encoding.readable:
            raise AgentError(self.encoding.unreadable_reason)
        seeds = int(self.config["seeds"])
        if not 0 <= seed < seeds:
            raise AgentError(f"--seed must lie in 0..{seeds - 1} (the run has {seeds} seeds), got {seed}")
        self.seed = seed
        self.env_name = self.config["env"]
        self.readout = self.encoding.readout
        self.env = envs.make(
            self.env_name, physics=physics or envs.default_physics(), **(self.config.get("env_options") or {})
        )
        self.encoder = load_encoder(self.config.get("encoder"))
        self.cache = build_cache(self.env_name, self.encoder, progress=False)
        self._cache_features: np.ndarray | None = None
        if check_encoder:
            self._check_encoder()
        stacked = read_policy_params(folder)
        self._encoding_params = read_encoding_params(folder, self.encoding, stacked)
        try:
            self._encoding = build_encoding(self.encoding, one_seed_params(self._encoding_params, seed))
        except EncodingError as error:
            raise AgentError(str(error)) from None
        train_rows = np.flatnonzero(self.cache.is_train)
        self._train_codes = np.asarray(self._encoding(self.cache_features()[train_rows]))
        self._train_goals = self.cache.goal_ids[train_rows]
        self.code_size = int(self._train_codes.shape[1])
        if self.code_size != self.encoding.code_size:
            raise AgentError(
                f"the {self.encoding.kind} encoding of {folder} gives codes of size {self.code_size}, its record says "
                f"{self.encoding.code_size}"
            )
        networks = make_ppo_networks(
            self.env.observation_size, self.code_size, self.env.action_spec, tuple(self.config["ifp"]["hidden_sizes"])
        )
        # the policy's own parameters: an encoding stored with them is applied by ``self._encoding``
        source = self.encoding.params
        own = source.entry if source.source == POLICY_SOURCE else None
        self._policy_params = jax.tree.map(
            lambda x: np.asarray(x)[seed], {k: v for k, v in stacked.items() if k != own}
        )
        self._make_policy = make_inference_fn(networks)
        self._episode = jax.jit(self._episode_fn, static_argnames=("deterministic",))
        self._batched_episodes: dict[bool, Any] = {}
        self._understanding: Understanding | None = None
        self._polarity: tuple | None = None  # (members, config) of the polarity classifier, or () when none fits
        self._calibration: Calibration | None = None
        self._clause_parser: tuple | None = None  # (params, config) of the clause parser, or () when none fits

    # --- language --------------------------------------------------------------------------------------------
    def _check_encoder(self) -> None:
        record_path = self.folder / LANGUAGE_RECORD
        if not record_path.is_file():
            return  # runs made before the record existed: the encoder option in config.json is all there is
        try:
            record = json.loads(record_path.read_bytes())
        except ValueError as error:
            raise _damaged(record_path, f"not valid JSON: {error}", self.folder) from None
        if not isinstance(record, dict):
            raise _damaged(record_path, "not a language record", self.folder)
        if record.get("weights_sha256") != self.encoder.weights_sha256 or record.get("cache_key") != self.cache.key:
            raise AgentError(
                f"the encoder found ({self.encoder.name}, weights sha256 {self.encoder.weights_sha256[:12]}) is not "
                f"the one the run trained with ({record.get('encoder_name')}, {str(record.get('weights_sha256'))[:12]})"
            )

    @property
    def continuous_codes(self) -> bool:
        """True for encodings whose codes are compared by distance, not equality (e.g. BERT-continuous)."""
        return self.encoding.continuous

    def encode(self, sentences: str | Sequence[str]) -> np.ndarray:
        """(S, F) (or (S, T, D) token states) the features the run's encoding reads of each sentence."""
        sentences = [sentences] if isinstance(sentences, str) else list(_sentence_list(sentences))
        for sentence in sentences:
            if not isinstance(sentence, str):
                raise TypeError(f"a sentence is a str, got {type(sentence).__name__}: {sentence!r}")
            if not sentence.strip():
                raise AgentError("a sentence is empty")
        try:
            features = features_with_cache(
                sentences,
                self.cache.sentences,
                self.cache_features(),
                lambda fresh: sentence_features(self.encoder, fresh, self.readout),
            )
        except ValueError as error:
            raise AgentError(str(error)) from None
        return features.astype(np.float32)

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

    # --- confidence ------------------------------------------------------------------------------------------
    @property
    def calibrated(self) -> bool:
        """Whether the run has its own confidence calibration (``confidence.json`` in its method folder)."""
        return (self.folder / CONFIDENCE_FILE).is_file()

    @property
    def calibration(self) -> Calibration:
        """The run's confidence calibration, or ``default_calibration()`` when it has none."""
        if self._calibration is None:
            self._calibration = read_calibration(self.folder) if self.calibrated else default_calibration()
        return self._calibration

    @calibration.setter
    def calibration(self, calibration: Calibration) -> None:
        self._calibration = calibration

    @property
    def understanding(self) -> Understanding:
        """The confidence measures of the run's encoding (every seed's translator; built on first use)."""
        if self._understanding is None:
            rows = np.flatnonzero(self.cache.is_train)
            try:
                self._understanding = Understanding(
                    self.encoding,
                    self._encoding_params,
                    self.cache_features()[rows],
                    self.cache.goal_ids[rows],
                    int(self.cache.num_goals),
                    embedding_dim=self.encoder.embedding_dim,
                )
            except (EncodingError, ConfidenceError) as error:
                raise AgentError(str(error)) from None
        return self._understanding

    def understand(self, sentence: str) -> Verdict:
        """The verdict on one sentence: act on it (``"understood"``, its goal), ask (``"ambiguous"``, the likeliest
        goals) or refuse (``"not understood"``), with its calibrated confidence."""
        if not isinstance(sentence, str):
            raise TypeError(f"understand takes one sentence, a str; got {type(sentence).__name__}: {sentence!r}")
        return self.judge([sentence])[0]

    def judge(self, sentences: Sequence[str], features: np.ndarray | None = None) -> list[Verdict]:
        """The verdict on each sentence (``features``: their ``encode`` output, when already at hand). A sentence the
        polarity classifier reads as asking not to do its task, or to undo it, is not acted on, and its verdict says
        which task it contradicts."""
        sentences = list(sentences)
        features = self.encode(sentences) if features is None else features
        try:
            verdicts = self.understanding.judge(sentences, features, self.seed, self.calibration)
        except ConfidenceError as error:
            raise AgentError(str(error)) from None
        probabilities = self.polarity(sentences, features)
        if probabilities is None:
            return verdicts
        return [self._with_polarity(v, p) for v, p in zip(verdicts, probabilities, strict=True)]

    def polarity(self, sentences: Sequence[str], features: np.ndarray | None = None) -> np.ndarray | None:
        """(S, classes) the polarity classifier's probability of each of ``CLASSES`` per sentence, or None when no
        classifier reads this run's encoder (``features``: their ``encode`` output, when already at hand)."""
        if self._polarity is None:
            self._polarity = load_polarity(self.encoder) or ()
        if not self._polarity:
            return None
        params, config = self._polarity
        # the frozen classifier reads the token readout a token-reading agent has already encoded; a fine-tuned top
        # reads the states entering it, one more encoder call
        reused = features is not None and self.readout == TOKEN_READOUT and not config.tuned_layers
        try:
            states = features if reused else polarity_states(self.encoder, list(sentences), config)
        except ValueError as error:
            raise AgentError(str(error)) from None
        return polarity_probabilities(params, states, config, self.encoder.config if config.tuned_layers else None)

    def _with_polarity(self, verdict: Verdict, probabilities: np.ndarray) -> Verdict:
        """The verdict, refused with its reason when the sentence does not ask for its task, or names something the
        agent does not know. A sentence the calibration already refuses as naming no goal keeps its own reason for an
        unknown object (it is just as true, and the clause parser joins such a fragment to its neighbour)."""
        judged = int(judged_classes(probabilities[None], self._polarity[1])[0])
        if judged == POSITIVE:
            return verdict
        label = POLARITY_CLASSES[judged]
        if judged == UNKNOWN:
            if verdict.verdict == NOT_UNDERSTOOD:
                return dataclasses.replace(verdict, goal=None, polarity=label)
            reason = "names something this agent does not know"
            return dataclasses.replace(verdict, verdict=NOT_UNDERSTOOD, goal=None, polarity=label, reason=reason)
        goal = verdict.goal if verdict.goal is not None else verdict.likeliest
        task = task_phrase(self.env_name, goal, self.env.goal_names)
        reason = f'asks not to "{task}"' if label == "negated" else f'asks for the opposite of "{task}"'
        return dataclasses.replace(verdict, verdict=NOT_UNDERSTOOD, goal=None, polarity=label, reason=reason)

    @property
    def clause_parser(self) -> tuple | None:
        """``(params, config)`` of the clause parser ``plan`` reads (the shipped one, loaded on first use), or None
        when none reads this run's encoder; set it to try another."""
        if self._clause_parser is None:
            self._clause_parser = load_clause_parser(self.encoder) or ()
        return self._clause_parser or None

    @clause_parser.setter
    def clause_parser(self, parser: tuple | None) -> None:
        self._clause_parser = parser or ()

    def plan(self, sentence: str) -> Plan:
        """The clauses of a sentence that may ask for several tasks, in the order they are to be done, each with its
        verdict (``Plan``). The clause parser shipped beside the agents splits it; a sentence it reads as one clause,
        or when none reads this run's encoder, is judged as a whole, as ``understand`` judges it."""
        if not isinstance(sentence, str):
            raise TypeError(f"plan takes one sentence, a str; got {type(sentence).__name__}: {sentence!r}")
        return self.plans([sentence])[0]

    def plans(self, sentences: Sequence[str]) -> list[Plan]:
        """``plan`` of each sentence, parsed and judged in batches."""
        sentences = list(sentences)
        if self.clause_parser is None:
            return [Plan(s, (v,)) for s, v in zip(sentences, self.judge(sentences), strict=True)]
        params, config = self.clause_parser
        try:
            parsed = parse_clauses(params, self.encoder, sentences, config)
        except ValueError as error:  # longer than the encoder reads
            raise AgentError(str(error)) from None
        split = self._grounded(sentences, parsed)
        # a sentence read as one clause is judged as a whole, exactly as ``understand`` judges it; so is one whose
        # clauses are not all understood while the whole is (the parser cut one request where it should not have):
        # a split that does not read is never preferred to a whole that does. Only those sentences are judged whole.
        unread = [i for i, judged in enumerate(split) if judged is None or not all(v.acts for v in judged)]
        whole = dict(zip(unread, self.judge([sentences[i] for i in unread]) if unread else [], strict=True))
        plans = []
        for index, (sentence, judged) in enumerate(zip(sentences, split, strict=True)):
            verdict = whole.get(index)
            one = judged is None or (verdict is not None and verdict.acts)
            plans.append(Plan(sentence, (verdict,) if one else tuple(judged)))
        return plans

    def _grounded(self, sentences: list[str], parsed: list[list]) -> list[list[Verdict] | None]:
        """Per sentence, the verdicts of its clauses after joining what the parser cut but the agent reads as one
        request (a piece that names no task, cut where the parser was unsure; the same task named twice in a row);
        None when one clause is left. Each round judges the clauses of every sentence still changing in one call."""
        out: list[list[Verdict] | None] = [None] * len(sentences)
        pending = {i: clauses for i, clauses in enumerate(parsed) if len(clauses) > 1}
        while pending:
            verdicts = iter(self._clause_verdicts([clause for clauses in pending.values() for clause in clauses]))
            changed = {}
            for index, clauses in pending.items():
                judged = [next(verdicts) for _ in clauses]
                names_nothing = [v.goal is None and v.reason is None for v in judged]  # no task, no polarity
                joined = join_fragments(sentences[index], clauses, names_nothing, JOIN_BELOW)
                if joined is None:
                    joined = merge_repeated_tasks(sentences[index], clauses, [v.goal for v in judged])
                if len(joined) == len(clauses):
                    out[index] = judged
                elif len(joined) > 1:
                    changed[index] = joined
            pending = changed
        return out

    def _clause_verdicts(self, clauses: list) -> list[Verdict]:
        """The verdict of each clause: of its words that ask for its task (``Clause.asks``: the translator learned
        from single instructions, not from "and then ..."), unless the whole clause is refused for its polarity, so
        that a "don't" the parser took for a joining word still refuses the chain."""
        stripped = [index for index, clause in enumerate(clauses) if clause.task is not None]
        judged = self.judge([clause.text for clause in clauses] + [clauses[index].task for index in stripped])
        verdicts = judged[: len(clauses)]
        for index, verdict in zip(stripped, judged[len(clauses) :], strict=True):
            if verdicts[index].reason is None:
                verdicts[index] = verdict
        return verdicts

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
        if deterministic not in self._batched_episodes:  # one compiled program per mode, reused call after call

            def episode(key, code, goal):  # the outputs returned, not the actions and physics positions
                obs, _, _, valid, success = self._episode_fn(key, code, goal, deterministic)
                return obs, valid, success

            self._batched_episodes[deterministic] = jax.jit(jax.vmap(episode))
        obs, valid, success = jax.device_get(
            self._batched_episodes[deterministic](keys, jnp.asarray(codes, jnp.float32), jnp.asarray(goals, jnp.int32))
        )
        return np.asarray(obs), np.asarray(valid), np.asarray(success)

    def success_rate(
        self, codes: np.ndarray, goals: np.ndarray, rng: jax.Array, deterministic: bool = False
    ) -> np.ndarray:
        """(E,) success of one episode per (code, goal) row, all episodes vmapped in one call."""
        return self.episodes(codes, goals, rng, deterministic)[-1]

    # --- the task language generator ---------------------------------------------------------------------------
    @property
    def generator_params(self) -> Any | None:
        """This seed's TL generator parameters (TALAR's referential-game stage, ``GENERATOR_FILE`` of the run; a
        shipped agent carries them only where they were recovered), or None when the run has none: then the task
        language cannot tell whether a sub-task was done (``task_language``)."""
        if not hasattr(self, "_generator_params"):
            path = self.folder / GENERATOR_FILE
            if self.method != "talar" or "talar" not in self.config or not path.is_file():
                self._generator_params = None
            else:
                tree = _read_tree(path, self.folder, path.parent)
                if "generator" not in tree:
                    raise _damaged(path, "no generator parameters", self.folder, path.parent)
                self._generator_params = jax.tree.map(lambda x: np.asarray(x)[self.seed], tree["generator"])
        return self._generator_params

    def task_language(self, states: jax.Array, final_states: jax.Array) -> jax.Array:
        """(..., code_size) the TL generator's deterministic code of the change ``states -> final_states`` (env
        observations without a goal part): the code the translator learnt to give an instruction of what that
        change did. Pure JAX (jit / vmap it); ``AgentError`` when the run has no generator (``generator_params``)."""
        from talar_jax.task_language import TaskLanguageGenerator, TaskLanguageSpec

        params = self.generator_params
        if params is None:
            raise AgentError(f"the run in {self.folder} has no task-language generator ({GENERATOR_FILE})")
        talar = self.config["talar"]
        generator = TaskLanguageGenerator(
            TaskLanguageSpec(**talar["spec"]), tuple(talar["generator_hidden"]), float(talar["gumbel_temperature"])
        )
        return generator.apply(params, jnp.asarray(states, jnp.float32), jnp.asarray(final_states, jnp.float32), None)


def load(run_dir: str | Path, seed: int = 0, physics: str | None = None) -> Agent:
    """The agent of seed ``seed`` of a finished run folder (see the module docstring)."""
    return Agent(run_dir, seed=seed, physics=physics)


def read_shipped_model(encoder: BertEncoder, stem: str, command: str, folder: Path = SHIPPED_AGENTS_DIR):
    """``(parameters, record)`` of a language model shipped beside the agents as ``stem.msgpack`` and ``stem.json``,
    or None when there is none or it reads another encoder's token states than ``encoder``'s (a damaged file is one
    ``AgentError`` naming it and ``command``, which rebuilds it)."""
    import flax.serialization

    record_path, params_path = folder / f"{stem}.json", folder / f"{stem}.msgpack"
    if not record_path.is_file() or not params_path.is_file():
        return None
    rebuild = f"rebuild it with: {command}"
    try:
        record = json.loads(record_path.read_text())
    except json.JSONDecodeError:
        raise AgentError(f"{record_path} is damaged; {rebuild}") from None
    if record.get("encoder_cache_key") != encoder.cache_key:
        return None
    try:
        return flax.serialization.msgpack_restore(params_path.read_bytes()), record
    except ValueError:
        raise AgentError(f"{params_path} is damaged; {rebuild}") from None


def load_polarity(encoder: BertEncoder, folder: Path = SHIPPED_AGENTS_DIR) -> tuple[dict, PolarityConfig] | None:
    """The shipped polarity classifier's parameters (``PolarityModel``'s) and config, or None (see
    ``read_shipped_model``)."""
    shipped = read_shipped_model(encoder, POLARITY_STEM, "python -m experiments.polarity", folder)
    if shipped is None:
        return None
    params, record = shipped
    # a record from before the unknown class has no "classes": it tells its labels apart
    config = PolarityConfig(**{"classes": len(record.get("labels", POLARITY_CLASSES)), **record["config"]})
    if "params" not in params or ("top" in params["params"]) != bool(config.tuned_layers):
        raise AgentError(
            f"{folder / POLARITY_PARAMS} is not the classifier its record describes; rebuild it with: "
            "python -m experiments.polarity"
        )
    return params, config


def load_clause_parser(encoder: BertEncoder, folder: Path = SHIPPED_AGENTS_DIR):
    """The shipped clause parser's parameters and config, or None (see ``read_shipped_model``)."""
    shipped = read_shipped_model(encoder, CLAUSES_STEM, "python -m experiments.clauses", folder)
    if shipped is None:
        return None
    params, record = shipped
    return params, ClauseParserConfig(**record["config"])
