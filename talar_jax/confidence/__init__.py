"""Translation confidence: how sure a run is that it understood a sentence, and whether its agent should act.

Every sentence gets a ``Verdict`` (``verdict``): ``"understood"`` (the goal the agent pursues), ``"ambiguous"`` (the
sentence is about the things the agent knows but its goal is not clear: the likeliest goals with their scores) or
``"not understood"`` (the sentence names nothing the agent was trained on). Three measures, all computed from the
run's encoding (``scores.Understanding.measure`` gives them as ``measures.Measures``):

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

A ``Calibration`` (``calibration``) turns them into a confidence (a logistic regression on the ``FEATURES`` it names)
and a verdict: the agent acts when its own code decodes to a goal and the confidence reaches ``act_threshold``;
otherwise the sentence is ``"ambiguous"`` when its familiarity reaches ``familiar_threshold`` and ``"not
understood"`` below it. ``fit`` fits one on the measures of labelled sentences. Nothing here reads a file or knows a
method: the agent loader (``talar_jax.agent``) reads a run's encoding parameters and its ``confidence.json``, and
``experiments.calibrate`` gathers and measures the sentences; the encoding record's kind picks the scorer, and its
``continuous`` flag how codes decode to goals.
"""

from talar_jax.confidence.calibration import Calibration
from talar_jax.confidence.measures import FEATURES, ConfidenceError, Measures, goal_posterior
from talar_jax.confidence.scores import (
    CodeScorer,
    Understanding,
    decode_goals,
    goal_codes,
    pooled_embeddings,
    register_code_scorer,
)
from talar_jax.confidence.verdict import AMBIGUOUS, NOT_UNDERSTOOD, UNDERSTOOD, VERDICTS, Plan, Verdict

__all__ = [
    "AMBIGUOUS",
    "FEATURES",
    "NOT_UNDERSTOOD",
    "UNDERSTOOD",
    "VERDICTS",
    "Calibration",
    "CodeScorer",
    "ConfidenceError",
    "Measures",
    "Plan",
    "Understanding",
    "Verdict",
    "decode_goals",
    "goal_codes",
    "goal_posterior",
    "pooled_embeddings",
    "register_code_scorer",
]
