"""A calibration: how a run's confidence measures become a confidence and a verdict."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from talar_jax.checkpoint import check_record_keys, config_to_dict
from talar_jax.confidence.measures import FEATURES, ConfidenceError, Measures
from talar_jax.confidence.verdict import AMBIGUOUS, NOT_UNDERSTOOD, UNDERSTOOD, Verdict


@dataclasses.dataclass(frozen=True)
class Calibration:
    """How measures become a confidence and a verdict (a run's ``confidence.json``).

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
    def feature_matrix(self, measures: Measures, seed: int) -> np.ndarray:
        """(S, len(features)) the calibration's features of each sentence for acting seed ``seed``."""
        return measures.features(self.features, seed, self.temperature, self.ensemble)

    def confidence(self, measures: Measures, seed: int) -> np.ndarray:
        """(S,) the calibrated probability that acting seed ``seed`` pursues the meant goal (0 where its code
        decodes to no goal)."""
        x = (self.feature_matrix(measures, seed) - np.asarray(self.mean)) / np.asarray(self.scale)
        z = x @ np.asarray(self.coef) + self.intercept
        decoded = np.asarray(measures.decoded[seed])
        return np.where(decoded >= 0, np.exp(-np.logaddexp(0.0, -z)), 0.0)  # a sigmoid, overflow-free

    def verdicts(self, measures: Measures, seed: int, sentences: Sequence[str]) -> list[Verdict]:
        """The verdict of acting seed ``seed`` on each sentence of ``measures``."""
        measures.check_seed(seed)
        confidence = self.confidence(measures, seed)
        posteriors, _ = measures.goal_posteriors(seed, self.temperature, self.ensemble)
        familiarity = np.asarray(measures.familiarity, np.float64)
        out = []
        for i, sentence in enumerate(sentences):
            posterior = posteriors[i]
            order = np.argsort(-posterior, kind="stable")[: self.max_candidates]
            candidates = [(int(order[0]), float(posterior[order[0]]))]
            candidates += [(int(g), float(posterior[g])) for g in order[1:] if posterior[g] >= self.candidate_floor]
            decoded = int(measures.decoded[seed, i])
            if decoded >= 0 and confidence[i] >= self.act_threshold:
                verdict, goal = UNDERSTOOD, decoded
            elif familiarity[i] >= self.familiar_threshold:
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
                    familiarity=float(familiarity[i]),
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
