"""The nodes' small framework: descriptors of the one parameter list, no DDS."""

from __future__ import annotations

from galvo_sysid.monitor import parameters
from galvo_sysid.nodes import framework


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
