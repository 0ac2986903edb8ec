"""Topic names and their message types (galvo_sysid.interfaces.topics)."""

from __future__ import annotations

from galvo_sysid.interfaces.topics import (
    CURRENT_TOPIC,
    DIAGNOSTICS_TOPIC,
    DRIFT_TOPIC,
    ENCODER_TOPIC,
    GALVO_TOPICS,
    MOVE_SAMPLES,
    RESULT_TOPIC,
    SIGNAL_TOPICS,
    TOPIC_TYPES,
    absolute_topic,
)
from galvo_sysid.monitor.moves import SIGNALS


def test_relative_names_for_the_nodes_absolute_ones_for_bags() -> None:
    assert (CURRENT_TOPIC, ENCODER_TOPIC, RESULT_TOPIC, DRIFT_TOPIC) == (
        'galvo/current', 'galvo/encoder', 'galvo/modal_parameters', 'galvo/drift')
    assert GALVO_TOPICS == ('/galvo/current', '/galvo/encoder', '/galvo/modal_parameters',
                            '/galvo/drift')
    assert absolute_topic(CURRENT_TOPIC, namespace='/scanner_1/') == '/scanner_1/galvo/current'
    assert absolute_topic(CURRENT_TOPIC, namespace='left/a') == '/left/a/galvo/current'
    assert absolute_topic(DIAGNOSTICS_TOPIC, namespace='scanner_1') == '/diagnostics'


def test_signals_and_types() -> None:
    assert tuple(SIGNAL_TOPICS) == SIGNALS
    assert SIGNAL_TOPICS['encoder'] == ENCODER_TOPIC
    assert TOPIC_TYPES[CURRENT_TOPIC] == TOPIC_TYPES[ENCODER_TOPIC] == MOVE_SAMPLES
    assert set(TOPIC_TYPES) == {t.lstrip('/') for t in GALVO_TOPICS}
