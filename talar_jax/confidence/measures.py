"""The confidence measures of sentences: what every seed of a run's encoding makes of each, and the features a
calibration weighs for one acting seed."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

FEATURES: dict[str, str] = {
    "familiarity": "largest cosine similarity of the pooled encoder embedding to a training instruction's",
    "goal_logit": "logit of the (ensemble) goal posterior of the goal the acting seed's code decodes to",
    "runner_up_logit": "logit of the largest (ensemble) goal posterior among the other goals",
    "own_goal_logit": "logit of the acting seed's own goal posterior of its decoded goal",
}
"""The features a calibration may weigh (its ``features`` name them in order)."""

_EPS = 1e-6


class ConfidenceError(ValueError):
    """A calibration or measure the confidence cannot use (one line, meant for the user)."""


def goal_posterior(log_likelihood: np.ndarray, temperature: float) -> np.ndarray:
    """(..., G) softmax over goals of code log-likelihoods divided by ``temperature``."""
    z = np.asarray(log_likelihood, np.float64) / temperature
    z = z - z.max(-1, keepdims=True)
    e = np.exp(z)
    return e / e.sum(-1, keepdims=True)


def _logit(p: np.ndarray) -> np.ndarray:
    p = np.clip(np.asarray(p, np.float64), _EPS, 1.0 - _EPS)
    return np.log(p) - np.log1p(-p)


@dataclasses.dataclass(frozen=True)
class Measures:
    """What every seed of a run's encoding makes of S sentences (K seeds, G goals).

    Attributes:
        familiarity: (S,) largest cosine similarity to a training instruction (pooled encoder embeddings).
        log_likelihood: (K, S, G) each seed's log-likelihood of each goal's code.
        decoded: (K, S) the goal each seed's code decodes to, -1 for none.
    """

    familiarity: np.ndarray
    log_likelihood: np.ndarray
    decoded: np.ndarray

    @property
    def num_seeds(self) -> int:
        return int(self.decoded.shape[0])

    @classmethod
    def concatenate(cls, parts: Sequence[Measures]) -> Measures:
        """The measures of the sentences of ``parts``, in order (the parts measured the same seeds)."""
        return cls(
            np.concatenate([p.familiarity for p in parts], axis=0),
            np.concatenate([p.log_likelihood for p in parts], axis=1),
            np.concatenate([p.decoded for p in parts], axis=1),
        )

    def check_seed(self, seed: int) -> None:
        if not 0 <= seed < self.num_seeds:
            raise ConfidenceError(f"seed {seed} is not among the {self.num_seeds} seeds of the encoding")

    def goal_posteriors(self, seed: int, temperature: float, ensemble: bool) -> tuple[np.ndarray, np.ndarray]:
        """``(posterior (S, G), own (S, G))``: the goal posterior a calibration reads (the mean over seeds for an
        ``ensemble``, else the acting seed's) and the acting seed's own."""
        posteriors = goal_posterior(self.log_likelihood, temperature)
        own = posteriors[seed]
        return (posteriors.mean(0) if ensemble else own), own

    def features(self, names: Sequence[str], seed: int, temperature: float, ensemble: bool) -> np.ndarray:
        """(S, len(names)) the ``FEATURES`` of each sentence for acting seed ``seed``; the goal they are about is
        the one its code decodes to, else its likeliest."""
        posterior, own = self.goal_posteriors(seed, temperature, ensemble)
        decoded = np.asarray(self.decoded[seed])
        rows = np.arange(len(decoded))
        goal = np.where(decoded >= 0, decoded, own.argmax(1))

        def feature(name: str) -> np.ndarray:
            if name == "familiarity":
                return np.asarray(self.familiarity, np.float64)
            if name == "goal_logit":
                return _logit(posterior[rows, goal])
            if name == "own_goal_logit":
                return _logit(own[rows, goal])
            if name == "runner_up_logit":
                others = posterior.copy()
                others[rows, goal] = -np.inf
                return _logit(others.max(1))
            raise ConfidenceError(f"unknown confidence feature {name!r}; valid: {', '.join(FEATURES)}")

        return np.stack([feature(name) for name in names], axis=1)
