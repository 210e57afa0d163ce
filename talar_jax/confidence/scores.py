"""The scores of a run's encoding: every seed's codes of a sentence, each goal's code log-likelihood under them, and
the sentence's familiarity to the run's training instructions (``Understanding.measure``)."""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from talar_jax.confidence.calibration import Calibration
from talar_jax.confidence.measures import ConfidenceError, Measures
from talar_jax.confidence.verdict import Verdict
from talar_jax.encodings import TRANSLATOR, EncodingArtifact, EncodingError, build_encoding
from talar_jax.language import TOKEN_READOUT
from talar_jax.task_language import Translator, decode_translation, split_task_language


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


class Understanding:
    """The confidence measures of a run's encoding: every seed's codes, goal codes and goal log-likelihoods, and
    the familiarity of a sentence to the run's training instructions.

    Args:
        artifact: the run's encoding record.
        params: the encoding's parameters of every seed (leading axis), as the run stores them (the agent loader
            reads them: ``talar_jax.agent.read_encoding_params``).
        train_features: (N, ...) the encoding's input features of the run's training instructions.
        train_goals: (N,) their goals.
        num_goals: the env's number of goals.
        embedding_dim: the encoder's embedding size (sentence readouts start with the pooled embedding).
    """

    def __init__(
        self,
        artifact: EncodingArtifact,
        params: Any,
        train_features: np.ndarray,
        train_goals: np.ndarray,
        num_goals: int,
        embedding_dim: int | None = None,
    ):
        self.artifact = artifact
        self.num_goals = int(num_goals)
        self.embedding_dim = embedding_dim
        self.train_goals = np.asarray(train_goals)
        self.reference = pooled_embeddings(train_features, artifact.readout, embedding_dim)
        build = _SCORERS.get(artifact.kind)
        stacked = jax.tree.map(np.asarray, params)
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
            self._per_seed = [
                build_encoding(artifact, jax.tree.map(lambda x, k=k: x[k], stacked)) for k in range(self.num_seeds)
            ]
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

    def measure(self, features: np.ndarray) -> Measures:
        """Every seed's ``Measures`` of the sentences whose encoding input is ``features``."""
        codes = self.codes(features)
        return Measures(self.familiarity(features), self.log_likelihoods(features, codes), self.decode(codes))

    def judge(
        self, sentences: Sequence[str], features: np.ndarray, seed: int, calibration: Calibration
    ) -> list[Verdict]:
        """The verdict of acting seed ``seed`` on each sentence (by ``calibration.for_seeds`` of the seeds held)."""
        calibration = calibration.for_seeds(self.num_seeds)
        return calibration.verdicts(self.measure(features), seed, sentences)
