"""The nodes' small framework: descriptors of the one parameter list, names kept (no DDS)."""

from __future__ import annotations

from galvo_sysid.interfaces import topics
from galvo_sysid.monitor import parameters
from galvo_sysid.nodes import driver_node, framework, sysid_node, watchdog_node


def test_the_nodes_declare_the_one_parameter_list() -> None:
    assert sysid_node.PARAMETERS is parameters.SYSID_PARAMETERS
    assert watchdog_node.PARAMETERS is parameters.WATCHDOG_PARAMETERS
    assert driver_node.PARAMETERS is parameters.DRIVER_PARAMETERS
    assert watchdog_node.tolerance_specs is parameters.tolerance_specs


def test_descriptors() -> None:
    specs = {s.name: s for s in parameters.SYSID_PARAMETERS}
    window = framework.descriptor(specs['window_size'])
    assert (window.integer_range[0].from_value, window.integer_range[0].to_value) == \
        (2, 100_000)
    assert not window.read_only
    method = framework.descriptor(specs['method'])
    assert method.description == 'identification method (one of: refined, paper-A, paper-B)'
    timeout = framework.descriptor(specs['pair_timeout'])  # (0, 3600]: no ROS range
    assert not timeout.floating_point_range
    tolerance = framework.descriptor(
        next(s for s in parameters.WATCHDOG_PARAMETERS if s.name == 'tolerances.k0'))
    assert tolerance.dynamic_typing
    assert tolerance.description.endswith('(optional number)')
    queue = framework.descriptor(specs['queue_size'])
    assert queue.read_only


def test_names_kept_where_they_were() -> None:
    assert framework.ParamSpec is parameters.ParamSpec
    assert framework.RELIABILITY is parameters.RELIABILITY
    assert (framework.CURRENT_TOPIC, framework.ENCODER_TOPIC, framework.RESULT_TOPIC,
            framework.DRIFT_TOPIC, framework.DIAGNOSTICS_TOPIC) == (
        topics.CURRENT_TOPIC, topics.ENCODER_TOPIC, topics.RESULT_TOPIC, topics.DRIFT_TOPIC,
        topics.DIAGNOSTICS_TOPIC)
