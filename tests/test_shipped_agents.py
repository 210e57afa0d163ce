"""The agents shipped in the package (``talar_jax/agents``) load by name, read sentences and still reach the success
the run they came from recorded for their seed: a code change that breaks them fails here, not in a user's hands."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from talar_jax.agent import SHIPPED_RECORD, AgentError, load, shipped_agents

EPISODES = 200
"""Episodes per split: with the record's 80 the two success rates differ by more than ``TOLERANCE`` with a
probability far below 1 % when the policy is unchanged."""


def _tolerance(p_recorded: float) -> float:
    """Four standard errors of the difference between our rate (``EPISODES``) and the record's (80 episodes), with
    the rate floored at 2 % so a perfect record does not demand a perfect rerun."""
    p = min(max(p_recorded, 0.02), 0.98)
    return 4 * np.sqrt(p * (1 - p) * (1 / EPISODES + 1 / 80))


def _split_success(agent, split: str, rng: jax.Array) -> float:
    """Success over ``EPISODES`` episodes of the split's instructions, goals drawn uniformly as the training run's
    evaluation draws them, each episode with a random instruction of its goal."""
    cache = agent.cache
    rows = np.flatnonzero(cache.is_train if split == "train" else ~cache.is_train)
    goals = np.unique(cache.goal_ids[rows])
    picker = np.random.default_rng(0 if split == "train" else 1)
    episode_goals = picker.choice(goals, EPISODES)
    sentence_rows = np.array([picker.choice(rows[cache.goal_ids[rows] == g]) for g in episode_goals])
    codes = agent.translate_features(agent.cache_features()[sentence_rows])
    return float(np.mean(agent.success_rate(codes, episode_goals, rng)))


@pytest.mark.parametrize("name", ["clevr", "kitchen"])
def test_a_shipped_agent_reaches_its_recorded_success(name):
    import json

    assert name in shipped_agents()
    agent = load(name)
    record = json.loads((agent.folder / SHIPPED_RECORD).read_text())
    assert record["env"] == agent.env_name == name
    for split, key in (("train", 0), ("test", 1)):
        ours = _split_success(agent, split, jax.random.key(key))
        recorded = record["final_success"][split]
        assert abs(ours - recorded) <= _tolerance(recorded), (split, ours, recorded)


def test_an_unknown_agent_name_is_one_line():
    with pytest.raises(AgentError, match="no shipped agent has its name") as error:
        load("no-such-agent")
    assert "\n" not in str(error.value) and "clevr" in str(error.value)
