"""Translation confidence: how sure a run is that it understood a sentence, and whether its agent should act.

Every sentence gets a ``Verdict``: ``"understood"`` (the goal the agent pursues), ``"ambiguous"`` (the sentence is
about the things the agent knows but its goal is not clear: the likeliest goals with their scores) or ``"not
understood"`` (the sentence names nothing the agent was trained on). Three measures, all computed from the run:

- **familiarity**: the largest cosine similarity between the sentence's pooled encoder embedding and those of the
  run's training instructions (the sentence-transformers readout: mean of the encoder's last hidden states, L2
  normalised; derived from whatever features the run's encoding reads, see ``pooled_embeddings``). A sentence about
  a fridge or a sandwich is far from every training instruction.
- **goal posterior**: for each goal g of the env, the log-likelihood under the translator's heads (independent
  Bernoulli predicates, categorical arguments: Eq. 3 of the paper) of g's code, the code most of g's training
  instructions translate to; a softmax over goals at a calibrated temperature gives ``q(g | sentence)``. Encodings
  that only give hard codes (kinds without a registered ``CodeScorer``) put all the mass on the goal their code
  decodes to.
- **ensemble**: the mean of ``q`` over the run's seeds' encodings (all of them are stored with the run and cost one
  small forward pass each); seeds that read a sentence differently spread the mass.

A ``Calibration`` (``confidence.json`` in the run's method folder, written by ``python -m experiments.calibrate``)
turns them into a confidence (a logistic regression fit on held-out sentences, see ``FEATURES``) and a verdict: the
agent acts when its own code decodes to a goal and the confidence reaches ``act_threshold``; otherwise the sentence
is ``"ambiguous"`` when its familiarity reaches ``familiar_threshold`` and ``"not understood"`` below it. Nothing here
knows a method: the encoding record's kind picks the scorer, and its ``continuous`` flag how codes decode to goals.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from talar_jax.checkpoint import check_record_keys, config_to_dict, read_json_record, write_json_atomic
from talar_jax.encodings import (
    TRANSLATOR,
    EncodingArtifact,
    EncodingError,
    make_encoding,
    stored_encoding_params,
)
from talar_jax.language import TOKEN_READOUT
from talar_jax.task_language import Translator, decode_translation, split_task_language

CONFIDENCE_FILE = "confidence.json"
UNDERSTOOD = "understood"
AMBIGUOUS = "ambiguous"
NOT_UNDERSTOOD = "not understood"
VERDICTS = (UNDERSTOOD, AMBIGUOUS, NOT_UNDERSTOOD)

FEATURES: dict[str, str] = {
    "familiarity": "largest cosine similarity of the pooled encoder embedding to a training instruction's",
    "goal_logit": "logit of the (ensemble) goal posterior of the goal the acting seed's code decodes to",
    "runner_up_logit": "logit of the largest (ensemble) goal posterior among the other goals",
    "own_goal_logit": "logit of the acting seed's own goal posterior of its decoded goal",
}
"""The measures a calibration may weigh (its ``features`` name them in order)."""

_EPS = 1e-6


class ConfidenceError(ValueError):
    """A calibration file or run the confidence measure cannot use (one line, meant for the user)."""


@dataclasses.dataclass(frozen=True)
class Verdict:
    """What an agent makes of one sentence.

    Attributes:
        sentence: the sentence.
        verdict: ``"understood"``, ``"ambiguous"`` or ``"not understood"``.
        goal: the goal the agent pursues (``"understood"`` only; None otherwise).
        confidence: the calibrated probability that acting on the sentence pursues the goal it means (0 when the
            acting seed's code decodes to no goal).
        candidates: the likeliest goals with their (ensemble) posterior, best first (at most the calibration's
            ``max_candidates``, each at least its ``candidate_floor`` but always the first).
        familiarity: the sentence's largest cosine similarity to a training instruction (pooled encoder embedding).
        decoded: the goal the acting seed's own code decodes to (None when no training instruction has that code).
    """

    sentence: str
    verdict: str
    goal: int | None
    confidence: float
    candidates: tuple[tuple[int, float], ...]
    familiarity: float
    decoded: int | None

    @property
    def acts(self) -> bool:
        """Whether the agent acts on the sentence without being told to."""
        return self.verdict == UNDERSTOOD

    @property
    def likeliest(self) -> int:
        """The goal of the first candidate (what ``--act-anyway`` would be scored on when no goal is decoded)."""
        return self.candidates[0][0]

    def to_json(self, goal_names: Sequence[str] | None = None) -> dict[str, Any]:
        """A JSON-serialisable record (goal names added when ``goal_names`` is given)."""

        def name(goal):
            return None if goal is None or goal_names is None else goal_names[goal]

        record = {
            "sentence": self.sentence,
            "verdict": self.verdict,
            "goal": self.goal,
            "confidence": round(float(self.confidence), 4),
            "candidates": [{"goal": g, "score": round(float(s), 4)} for g, s in self.candidates],
            "familiarity": round(float(self.familiarity), 4),
            "decoded_goal": self.decoded,
        }
        if goal_names is not None:
            record["goal_name"] = name(self.goal)
            record["decoded_goal_name"] = name(self.decoded)
            for candidate in record["candidates"]:
                candidate["name"] = name(candidate["goal"])
        return record

    def describe(self, goal_names: Sequence[str]) -> str:
        """One line for a person: the goal, or why the agent does not act and what it could mean."""
        listed = [f"{goal_names[g]} ({s:.2f})" for g, s in self.candidates]
        if self.verdict == UNDERSTOOD:
            return f'understood: "{self.sentence}" means {goal_names[self.goal]} (confidence {self.confidence:.2f})'
        if self.verdict == AMBIGUOUS:
            if len(listed) == 1:
                options = f"perhaps {listed[0]}?"
            else:
                options = "could be " + ", ".join(listed[:-1]) + f" or {listed[-1]}"
            return (
                f'not sure: "{self.sentence}" {options} (confidence {self.confidence:.2f}); rephrase, or --act-anyway'
            )
        return (
            f'not understood: "{self.sentence}" names nothing this agent was trained on (confidence '
            f"{self.confidence:.2f}, closest: {listed[0]}); rephrase, or --act-anyway"
        )


@dataclasses.dataclass(frozen=True)
class Calibration:
    """How measures become a confidence and a verdict (``confidence.json``).

    Attributes:
        temperature: the goal posterior's softmax temperature over code log-likelihoods.
        ensemble: average the goal posterior over the run's seeds (else the acting seed's alone).
        features: the measures the confidence weighs (names of ``FEATURES``), in the order of the weights.
        mean, scale: each feature's standardisation (``(x - mean) / scale``).
        coef, intercept: the logistic regression on the standardised features.
        act_threshold: the confidence from which the agent acts.
        familiar_threshold: the familiarity from which a sentence it does not act on is ``"ambiguous"`` rather than
            ``"not understood"``.
        max_candidates: how many candidate goals a verdict lists at most.
        candidate_floor: the smallest posterior a listed candidate (after the first) has.
        single_seed: for an ensemble calibration, the one fit on each seed's own posterior, which an agent holding a
            single seed's encoding (a shipped agent) uses instead (``for_seeds``).
        source: provenance (the run, the data, the command, what was measured; free-form JSON).
    """

    temperature: float
    ensemble: bool
    features: tuple[str, ...]
    mean: tuple[float, ...]
    scale: tuple[float, ...]
    coef: tuple[float, ...]
    intercept: float
    act_threshold: float
    familiar_threshold: float
    max_candidates: int = 3
    candidate_floor: float = 0.05
    single_seed: Calibration | None = None
    source: dict[str, Any] = dataclasses.field(default_factory=dict, compare=False)

    def __post_init__(self):
        for name in ("features", "mean", "scale", "coef"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        unknown = [f for f in self.features if f not in FEATURES]
        if unknown:
            raise ConfidenceError(f"unknown confidence features {unknown}; valid: {', '.join(FEATURES)}")
        sizes = {len(self.features), len(self.mean), len(self.scale), len(self.coef)}
        if len(sizes) != 1 or not self.features:
            raise ConfidenceError("a calibration needs one mean, scale and weight per feature, and a feature at least")
        if not (self.temperature > 0 and all(s > 0 for s in self.scale)):
            raise ConfidenceError("a calibration's temperature and scales must be > 0")
        if not 0.0 <= self.act_threshold <= 1.0:
            raise ConfidenceError(f"act_threshold must lie in [0, 1], got {self.act_threshold}")
        if self.max_candidates < 1:
            raise ConfidenceError(f"max_candidates must be >= 1, got {self.max_candidates}")
        if self.single_seed is not None and (not self.ensemble or self.single_seed.ensemble):
            raise ConfidenceError("only an ensemble calibration holds a single-seed one, and that one is no ensemble")

    def for_seeds(self, num_seeds: int) -> Calibration:
        """The calibration for an encoding of ``num_seeds`` seeds: an ensemble needs two at least, else its
        single-seed calibration is used (``ConfidenceError`` when it has none)."""
        if not self.ensemble or num_seeds > 1:
            return self
        if self.single_seed is None:
            raise ConfidenceError(
                "the calibration averages several seeds' translators and the agent holds one; calibrate it again "
                "(python -m experiments.calibrate writes a single-seed calibration beside the ensemble's)"
            )
        return self.single_seed

    # --- the decision ----------------------------------------------------------------------------------------
    def feature_matrix(self, measures: Measures) -> np.ndarray:
        """(S, len(features)) the calibration's features of each sentence."""
        return np.stack([measures.feature(name) for name in self.features], axis=1)

    def confidence(self, measures: Measures) -> np.ndarray:
        """(S,) the calibrated probability that acting pursues the meant goal (0 where no goal is decoded)."""
        x = (self.feature_matrix(measures) - np.asarray(self.mean)) / np.asarray(self.scale)
        z = x @ np.asarray(self.coef) + self.intercept
        return np.where(measures.decoded >= 0, np.exp(-np.logaddexp(0.0, -z)), 0.0)  # a sigmoid, overflow-free

    def verdicts(self, measures: Measures, sentences: Sequence[str]) -> list[Verdict]:
        """The verdict on each sentence of ``measures``."""
        confidence = self.confidence(measures)
        out = []
        for i, sentence in enumerate(sentences):
            posterior = measures.posterior[i]
            order = np.argsort(-posterior, kind="stable")[: self.max_candidates]
            candidates = [(int(order[0]), float(posterior[order[0]]))]
            candidates += [(int(g), float(posterior[g])) for g in order[1:] if posterior[g] >= self.candidate_floor]
            decoded = int(measures.decoded[i])
            if decoded >= 0 and confidence[i] >= self.act_threshold:
                verdict, goal = UNDERSTOOD, decoded
            elif measures.familiarity[i] >= self.familiar_threshold:
                verdict, goal = AMBIGUOUS, None
            else:
                verdict, goal = NOT_UNDERSTOOD, None
            out.append(
                Verdict(
                    sentence=sentence,
                    verdict=verdict,
                    goal=goal,
                    confidence=float(confidence[i]),
                    candidates=tuple(candidates),
                    familiarity=float(measures.familiarity[i]),
                    decoded=decoded if decoded >= 0 else None,
                )
            )
        return out

    # --- JSON ------------------------------------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        """The ``confidence.json`` object: every field, tuples as lists, ``single_seed`` as its own object."""
        return config_to_dict(self)

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Calibration:
        required = {f.name for f in dataclasses.fields(cls) if f.default is dataclasses.MISSING}
        check_record_keys(data, cls, required - {"source", "single_seed"}, ConfidenceError, "calibration")
        try:
            values = {
                "temperature": float(data["temperature"]),
                "ensemble": bool(data["ensemble"]),
                "features": tuple(str(f) for f in data["features"]),
                "mean": tuple(float(v) for v in data["mean"]),
                "scale": tuple(float(v) for v in data["scale"]),
                "coef": tuple(float(v) for v in data["coef"]),
                "intercept": float(data["intercept"]),
                "act_threshold": float(data["act_threshold"]),
                "familiar_threshold": float(data["familiar_threshold"]),
            }
        except (TypeError, ValueError) as error:
            raise ConfidenceError(f"malformed calibration: {error}") from None
        for key in ("max_candidates", "candidate_floor"):
            if key in data:
                values[key] = int(data[key]) if key == "max_candidates" else float(data[key])
        if data.get("single_seed") is not None:
            values["single_seed"] = cls.from_json(data["single_seed"])
        return cls(**values, source=dict(data.get("source") or {}))

    def write(self, path: str | Path) -> Path:
        """Writes the calibration to ``path`` (a file, or a method folder: its ``confidence.json``), atomically."""
        path = Path(path)
        if path.is_dir():
            path = path / CONFIDENCE_FILE
        write_json_atomic(path, self.to_json())
        return path

    @classmethod
    def read(cls, path: str | Path) -> Calibration:
        """The calibration in ``path`` (a file, or a method folder's ``confidence.json``)."""
        path = Path(path)
        if path.is_dir():
            path = path / CONFIDENCE_FILE
        if not path.is_file():
            raise ConfidenceError(f"no calibration at {path}")
        return read_json_record(path, cls.from_json, ConfidenceError)

    @classmethod
    def default(cls) -> Calibration:
        """The calibration of a run that has none: the one fit on the kitchen TALAR run at the paper's budget
        (``results/abstention.md``); ``source["default"]`` is True so that callers can say so."""
        return cls.from_json(DEFAULT_CALIBRATION)


DEFAULT_CALIBRATION: dict[str, Any] = {
    "temperature": 3.0,
    "ensemble": True,
    "features": ["familiarity", "goal_logit", "runner_up_logit"],
    "mean": [0.6678, 2.8180, -3.7535],
    "scale": [0.2358, 2.7031, 2.5193],
    "coef": [0.9539, 2.1137, 0.0358],
    "intercept": 0.3456,
    "act_threshold": 0.4191,
    "familiar_threshold": 0.4881,
    "single_seed": {
        "temperature": 3.0,
        "ensemble": False,
        "features": ["familiarity", "goal_logit", "runner_up_logit"],
        "mean": [0.6678, 3.5588, -4.0641],
        "scale": [0.2358, 3.0254, 2.8325],
        "coef": [1.2844, 1.7578, -0.0302],
        "intercept": 0.3338,
        "act_threshold": 0.2791,
        "familiar_threshold": 0.4881,
    },
    "source": {
        "default": True,
        "fit_on": "the kitchen TALAR run at the paper's budget (translator stage, 5 seeds, all-MiniLM-L6-v2)",
        "study": "results/abstention.md",
    },
}
"""The calibration of the kitchen study (``python -m experiments.calibrate runs/kitchen``, ``results/abstention.md``),
used by runs that have none of their own: its familiarity is that of all-MiniLM-L6-v2, so it means little for
another encoder; calibrate such a run."""


# --- measures ------------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Measures:
    """The measures of S sentences for one acting seed.

    Attributes:
        familiarity: (S,) largest cosine similarity to a training instruction (pooled encoder embeddings).
        posterior: (S, G) the goal posterior the calibration reads (the ensemble's, or the acting seed's).
        own_posterior: (S, G) the acting seed's goal posterior.
        decoded: (S,) the goal the acting seed's code decodes to, -1 for none.
        seed_decoded: (K, S) the goal each seed's code decodes to (-1 for none), K the seeds measured.
    """

    familiarity: np.ndarray
    posterior: np.ndarray
    own_posterior: np.ndarray
    decoded: np.ndarray
    seed_decoded: np.ndarray

    def goal(self) -> np.ndarray:
        """(S,) the goal the confidence is about: the decoded goal, else the acting seed's likeliest."""
        return np.where(self.decoded >= 0, self.decoded, self.own_posterior.argmax(1))

    def feature(self, name: str) -> np.ndarray:
        """(S,) one of ``FEATURES``."""
        rows = np.arange(len(self.decoded))
        goal = self.goal()
        if name == "familiarity":
            return self.familiarity
        if name == "goal_logit":
            return _logit(self.posterior[rows, goal])
        if name == "own_goal_logit":
            return _logit(self.own_posterior[rows, goal])
        if name == "runner_up_logit":
            others = self.posterior.copy()
            others[rows, goal] = -np.inf
            return _logit(others.max(1))
        raise ConfidenceError(f"unknown confidence feature {name!r}; valid: {', '.join(FEATURES)}")


def _logit(p: np.ndarray) -> np.ndarray:
    p = np.clip(np.asarray(p, np.float64), _EPS, 1.0 - _EPS)
    return np.log(p) - np.log1p(-p)


def goal_posterior(log_likelihood: np.ndarray, temperature: float) -> np.ndarray:
    """(..., G) softmax over goals of code log-likelihoods divided by ``temperature``."""
    z = np.asarray(log_likelihood, np.float64) / temperature
    z = z - z.max(-1, keepdims=True)
    e = np.exp(z)
    return e / e.sum(-1, keepdims=True)


def pooled_embeddings(features: np.ndarray, readout: str, dim: int | None = None) -> np.ndarray:
    """(S, D) L2-normalised pooled sentence embeddings from an encoding's input features: the mean of the token
    states (readout ``"tokens"``, padding rows are zero), or the pooled embedding the sentence readouts start with
    (``dim`` entries; ``"sentence+prefixes"`` appends the prefixes' mean after them)."""
    features = np.asarray(features, np.float32)
    if readout == TOKEN_READOUT:
        real = np.any(features != 0, axis=-1, keepdims=True)
        pooled = (features * real).sum(-2) / np.maximum(real.sum(-2), 1)
    else:
        pooled = features[..., : dim or features.shape[-1]]
    return pooled / np.maximum(np.linalg.norm(pooled, axis=-1, keepdims=True), 1e-12)


def decode_goals(codes: np.ndarray, train_codes: np.ndarray, train_goals: np.ndarray, continuous: bool) -> np.ndarray:
    """(S,) the goal each code decodes to: the goal most training instructions with exactly that code have (-1 when
    none has it); for continuous codes, the goal of the nearest training instruction's code."""
    codes = np.asarray(codes, np.float32).reshape(len(codes), -1)
    out = np.full(len(codes), -1, np.int64)
    for i, code in enumerate(codes):
        if continuous:
            out[i] = int(train_goals[np.argmin(np.linalg.norm(train_codes - code, axis=1))])
            continue
        same = np.all(np.abs(train_codes - code) < 0.5, axis=1)
        if same.any():
            out[i] = int(Counter(train_goals[same].tolist()).most_common(1)[0][0])
    return out


def goal_codes(train_codes: np.ndarray, train_goals: np.ndarray, num_goals: int) -> np.ndarray:
    """(G, size) each goal's code: the one most of its training instructions translate to."""
    out = []
    for goal in range(num_goals):
        rows, counts = np.unique(np.asarray(train_codes)[train_goals == goal].round(3), axis=0, return_counts=True)
        if not len(rows):
            raise ConfidenceError(f"goal {goal} has no training instruction")
        out.append(rows[np.argmax(counts)])
    return np.stack(out).astype(np.float32)


# --- scorers: codes and code log-likelihoods of one kind of encoding ------------------------------------------
@dataclasses.dataclass(frozen=True)
class CodeScorer:
    """An encoding kind's ``codes(params, features) -> (S, size)`` hard codes (as the policy reads them) and
    ``log_likelihood(params, features, codes (G, size)) -> (S, G)`` of given codes; both pure, params first (so
    that seeds can be vmapped)."""

    codes: Callable[[Any, jax.Array], jax.Array]
    log_likelihood: Callable[[Any, jax.Array, jax.Array], jax.Array]


_SCORERS: dict[str, Callable[[EncodingArtifact], CodeScorer]] = {}


def register_code_scorer(kind: str, build: Callable[[EncodingArtifact], CodeScorer], *, replace: bool = False):
    """Lets the confidence measure read an encoding kind's per-head probabilities: ``build(artifact)`` returns its
    ``CodeScorer``. Kinds without one are measured on their hard codes alone."""
    if kind in _SCORERS and not replace:
        raise ValueError(f"a code scorer for kind {kind!r} is already registered (pass replace=True to replace it)")
    _SCORERS[kind] = build


def _translator_scorer(artifact: EncodingArtifact) -> CodeScorer:
    spec = artifact.spec
    translator = Translator(spec, artifact.hidden, artifact.readout == TOKEN_READOUT)

    def codes(params, features):
        return decode_translation(spec, translator.apply(params, features))

    def log_likelihood(params, features, goal_codes):
        logits = translator.apply(params, features)
        predicate_logits, argument_logits = split_task_language(spec, logits)  # (S, Npn), (S, Na, A)
        predicate_codes, argument_codes = split_task_language(spec, goal_codes)  # (G, Npn), (G, Na, A)
        predicates = jax.nn.log_sigmoid(predicate_logits) @ predicate_codes.T
        predicates += jax.nn.log_sigmoid(-predicate_logits) @ (1.0 - predicate_codes).T
        arguments = jnp.einsum("sna,gna->sg", jax.nn.log_softmax(argument_logits, -1), argument_codes)
        return predicates + arguments

    return CodeScorer(codes, log_likelihood)


register_code_scorer(TRANSLATOR, _translator_scorer)

_HARD_CODE_LOG_LIKELIHOOD = -30.0
"""Log-likelihood a hard-code encoding gives the goals its code does not decode to (the decoded goal gets 0)."""


def stacked_encoding_params(
    artifact: EncodingArtifact, method_folder: str | Path, policy_params: Mapping[str, Any] | None = None
) -> Any:
    """The encoding's parameters of every seed (leading axis), as the record says where they lie."""
    tree, _ = stored_encoding_params(artifact, method_folder, policy_params)
    return jax.tree.map(np.asarray, tree)


class Understanding:
    """The confidence measures of a run's encoding: every seed's codes, goal codes and goal log-likelihoods, and
    the familiarity of a sentence to the run's training instructions.

    Args:
        artifact: the run's encoding record.
        method_folder: its method folder (file paths of the record are relative to its parent).
        train_features: (N, ...) the encoding's input features of the run's training instructions.
        train_goals: (N,) their goals.
        num_goals: the env's number of goals.
        policy_params: the policy checkpoint's (seed-stacked) params, for encodings stored with the policy.
        embedding_dim: the encoder's embedding size (sentence readouts start with the pooled embedding).
    """

    def __init__(
        self,
        artifact: EncodingArtifact,
        method_folder: str | Path,
        train_features: np.ndarray,
        train_goals: np.ndarray,
        num_goals: int,
        policy_params: Mapping[str, Any] | None = None,
        embedding_dim: int | None = None,
    ):
        self.artifact = artifact
        self.num_goals = int(num_goals)
        self.embedding_dim = embedding_dim
        self.train_goals = np.asarray(train_goals)
        self.reference = pooled_embeddings(train_features, artifact.readout, embedding_dim)
        build = _SCORERS.get(artifact.kind)
        stacked = stacked_encoding_params(artifact, method_folder, policy_params)
        leaves = jax.tree.leaves(stacked)
        self.num_seeds = int(min(np.shape(leaf)[0] for leaf in leaves)) if leaves else 0
        if self.num_seeds < 1:
            raise EncodingError("the encoding's parameters hold no seed")
        self.scored = build is not None
        if build is not None:
            scorer = build(artifact)
            self._codes = jax.jit(jax.vmap(scorer.codes, in_axes=(0, None)))
            self._log_likelihood = jax.jit(jax.vmap(scorer.log_likelihood, in_axes=(0, None, 0)))
            self._stacked = stacked
        else:  # hard codes of each seed through the kind's registered encoding
            self._per_seed = [make_encoding(artifact, method_folder, k, policy_params) for k in range(self.num_seeds)]
        self.train_codes = self.codes(train_features)  # (K, N, size)
        self.goal_codes = np.stack([goal_codes(c, self.train_goals, self.num_goals) for c in self.train_codes])

    def codes(self, features: np.ndarray) -> np.ndarray:
        """(K, S, size) every seed's codes of the sentences."""
        features = jnp.asarray(features, jnp.float32)
        if self.scored:
            return np.asarray(self._codes(self._stacked, features))
        return np.stack([np.asarray(encode(features)) for encode in self._per_seed])

    def log_likelihoods(self, features: np.ndarray, codes: np.ndarray | None = None) -> np.ndarray:
        """(K, S, G) every seed's log-likelihood of each goal's code (hard-code kinds: 0 for the decoded goal,
        ``_HARD_CODE_LOG_LIKELIHOOD`` for the others, 0 everywhere when no goal is decoded)."""
        if self.scored:
            return np.asarray(
                self._log_likelihood(self._stacked, jnp.asarray(features, jnp.float32), jnp.asarray(self.goal_codes)),
                np.float64,
            )
        codes = self.codes(features) if codes is None else codes
        decoded = self.decode(codes)
        out = np.full((*decoded.shape, self.num_goals), _HARD_CODE_LOG_LIKELIHOOD)
        out[decoded < 0] = 0.0
        k, s = np.nonzero(decoded >= 0)
        out[k, s, decoded[k, s]] = 0.0
        return out

    def decode(self, codes: np.ndarray) -> np.ndarray:
        """(K, S) the goal each seed's code decodes to (-1 for none), by that seed's training codes."""
        return np.stack(
            [
                decode_goals(codes[k], self.train_codes[k], self.train_goals, self.artifact.continuous)
                for k in range(len(codes))
            ]
        )

    def familiarity(self, features: np.ndarray) -> np.ndarray:
        """(S,) largest cosine similarity of each sentence's pooled embedding to a training instruction's."""
        pooled = pooled_embeddings(features, self.artifact.readout, self.embedding_dim)
        return (pooled @ self.reference.T).max(1)

    def seed_measures(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(familiarity (S,), log-likelihoods (K, S, G), decoded goals (K, S))``: what ``measures`` reads, for
        every acting seed at once."""
        codes = self.codes(features)
        return self.familiarity(features), self.log_likelihoods(features, codes), self.decode(codes)

    def measures(
        self, features: np.ndarray, seed: int, calibration: Calibration, computed: tuple | None = None
    ) -> Measures:
        """The ``Measures`` of the sentences (their encoding input ``features``) for acting seed ``seed``
        (``computed``: ``seed_measures(features)`` when already at hand)."""
        if not 0 <= seed < self.num_seeds:
            raise ConfidenceError(f"seed {seed} is not among the {self.num_seeds} seeds of the encoding")
        familiarity, log_likelihood, decoded = computed if computed is not None else self.seed_measures(features)
        return measures_from(familiarity, log_likelihood, decoded, seed, calibration)

    def judge(self, sentences: Sequence[str], features: np.ndarray, seed: int, calibration: Calibration):
        """The verdict on each sentence for acting seed ``seed`` (by ``calibration.for_seeds`` of the seeds held)."""
        calibration = calibration.for_seeds(self.num_seeds)
        return calibration.verdicts(self.measures(features, seed, calibration), sentences)


def measures_from(
    familiarity: np.ndarray, log_likelihood: np.ndarray, decoded: np.ndarray, seed: int, calibration: Calibration
) -> Measures:
    """``Measures`` for acting seed ``seed`` from every seed's log-likelihoods (K, S, G) and decoded goals (K, S)."""
    posteriors = goal_posterior(log_likelihood, calibration.temperature)
    own = posteriors[seed]
    return Measures(
        familiarity=np.asarray(familiarity, np.float64),
        posterior=posteriors.mean(0) if calibration.ensemble else own,
        own_posterior=own,
        decoded=np.asarray(decoded[seed]),
        seed_decoded=np.asarray(decoded),
    )
