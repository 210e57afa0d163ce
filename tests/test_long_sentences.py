"""Sentences longer than the token readout's 32 slots are read at their own width, not refused; only the encoder's
position limit bounds a sentence, and passing it is one line."""

from __future__ import annotations

import numpy as np
import pytest

LONG = (
    "Hello there, if it is not too much trouble for you today and you happen to have a free moment, would you please "
    "be so kind as to open the microwave door for me, thank you very much indeed"
)
SHORT = "Open the microwave door"


@pytest.fixture(scope="module")
def kitchen_agent():
    from talar_jax import agent

    return agent.load("kitchen")


def test_a_sentence_longer_than_the_token_slots_is_understood(kitchen_agent):
    from talar_jax.language import TOKEN_SLOTS

    pieces = len(kitchen_agent.encoder.tokenize([LONG])[0])
    assert pieces + 2 > TOKEN_SLOTS  # the case that used to be refused
    verdict = kitchen_agent.understand(LONG)
    assert verdict.acts and verdict.goal == kitchen_agent.understand(SHORT).goal


def test_reading_beside_a_long_sentence_does_not_change_a_short_ones_code(kitchen_agent):
    alone = kitchen_agent.translate([SHORT])
    beside = kitchen_agent.translate([LONG, SHORT])
    np.testing.assert_array_equal(alone[0], beside[1])
    assert kitchen_agent.encode([LONG, SHORT]).shape[1] > kitchen_agent.encode([SHORT]).shape[1]


def test_a_sentence_past_the_encoders_positions_is_one_line(kitchen_agent):
    from talar_jax.agent import AgentError
    from talar_jax.language import max_word_pieces

    too_long = " ".join(["microwave"] * (max_word_pieces(kitchen_agent.encoder) + 1))
    with pytest.raises(AgentError) as raised:
        kitchen_agent.understand(too_long)
    message = str(raised.value)
    assert "\n" not in message and "word pieces" in message and "split it" in message


def test_stack_features_pads_token_rows_to_the_widest():
    from talar_jax.language import stack_features

    rows = [np.ones((3, 2), np.float32), np.full((5, 2), 2.0, np.float32)]
    stacked = stack_features(rows)
    assert stacked.shape == (2, 5, 2)
    np.testing.assert_array_equal(stacked[0, 3:], 0.0)
    np.testing.assert_array_equal(stacked[1], rows[1])
    assert stack_features([np.zeros(4), np.ones(4)]).shape == (2, 4)
