"""What an agent makes of one sentence: act on it, ask which goal it means, or say it does not understand."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

UNDERSTOOD = "understood"
AMBIGUOUS = "ambiguous"
NOT_UNDERSTOOD = "not understood"
VERDICTS = (UNDERSTOOD, AMBIGUOUS, NOT_UNDERSTOOD)


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
        polarity: what the sentence asks of the task it names (``talar_jax.language.polarity.CLASSES``): to do it
            ("positive"), not to do it ("negated") or to undo it ("opposite"), or whether it names something the
            agent does not know ("unknown"); the agent acts on positive ones only.
        reason: why a sentence that names a known task is not acted on, in words for a person (for example
            'asks for the opposite of "open the microwave door"', or 'names something this agent does not know');
            None otherwise.
    """

    sentence: str
    verdict: str
    goal: int | None
    confidence: float
    candidates: tuple[tuple[int, float], ...]
    familiarity: float
    decoded: int | None
    polarity: str = "positive"
    reason: str | None = None

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
            "polarity": self.polarity,
            "reason": self.reason,
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
        if self.reason is not None:
            return f'not understood: "{self.sentence}" {self.reason}; rephrase, or --act-anyway'
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
class Plan:
    """What an agent makes of a sentence that may ask for several tasks: its clauses in the order they are to be
    done, each with its own verdict. The agent acts on the chain only when it acts on every clause.

    Attributes:
        sentence: the sentence.
        steps: one ``Verdict`` per clause (its ``sentence`` is the clause's text), in the order to be done; a sentence
            that asks for one task is one step, judged as a whole.
    """

    sentence: str
    steps: tuple[Verdict, ...]

    @property
    def acts(self) -> bool:
        """Whether the agent acts on the chain: every clause understood."""
        return all(step.acts for step in self.steps)

    @property
    def goals(self) -> tuple[int | None, ...]:
        """The goal of each clause, in the order to be done (None where a clause is not understood)."""
        return tuple(step.goal for step in self.steps)

    @property
    def blocking(self) -> int | None:
        """The index of the first clause the agent does not act on (None when it acts on all)."""
        return next((index for index, step in enumerate(self.steps) if not step.acts), None)

    def to_json(self, goal_names: Sequence[str], reached: Sequence[int | None] | None = None) -> dict[str, Any]:
        """``{"sentence", "acted", "plan": [{"clause", "goal" (its name), "verdict", "reached_step", "goal_id",
        ...}]}`` (the other keys: the clause's ``Verdict.to_json``);
        ``reached``: the step at which each clause's task was reached when the chain was run (None: not run, or not
        reached)."""
        reached = list(reached) if reached is not None else [None] * len(self.steps)
        plan = []
        for step, at in zip(self.steps, reached, strict=True):
            record = step.to_json(goal_names)
            plan.append(
                {
                    "clause": step.sentence,
                    "goal": record["goal_name"],
                    "verdict": step.verdict,
                    "reached_step": at,
                    "goal_id": step.goal,
                    **{k: v for k, v in record.items() if k not in ("sentence", "goal", "goal_name", "verdict")},
                }
            )
        return {"sentence": self.sentence, "acted": self.acts, "plan": plan}

    def describe(self, goal_names: Sequence[str]) -> str:
        """Lines for a person: one per clause, or the single verdict of a one-task sentence; when the agent does not
        act, the first line names the clause that stops it."""
        if len(self.steps) == 1:
            return self.steps[0].describe(goal_names)
        lines = []
        if not self.acts:
            index = self.blocking
            lines.append(
                f'not acted on: clause {index + 1} of {len(self.steps)}, "{self.steps[index].sentence}", is not '
                "understood; rephrase it, or --act-anyway"
            )
        else:
            lines.append(f"a chain of {len(self.steps)} tasks, done in this order:")
        lines += [f"  {index + 1}. {step.describe(goal_names)}" for index, step in enumerate(self.steps)]
        return "\n".join(lines)
