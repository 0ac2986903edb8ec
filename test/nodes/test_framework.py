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


def test_every_verdict_level_has_a_diagnostic_level() -> None:
    from diagnostic_msgs.msg import DiagnosticStatus

    from galvo_sysid.monitor import verdict

    assert set(framework.DIAGNOSTIC_LEVELS) == set(range(len(verdict.LEVEL_NAMES)))
    assert framework.DIAGNOSTIC_LEVELS[verdict.MISMATCH] == DiagnosticStatus.ERROR
    assert framework.DIAGNOSTIC_LEVELS[verdict.STALE] == DiagnosticStatus.STALE

def test_starting_a_node_limits_blas_unless_the_user_set_it() -> None:
    """The node modules import galvo_sysid.nodes first, which limits BLAS before numpy loads."""
    import os
    import subprocess
    import sys

    from galvo_sysid import BLAS_THREAD_VARIABLES

    code = ('import os, sys\n'
            'import galvo_sysid.nodes\n'
            'print("numpy" in sys.modules)\n'
            'import galvo_sysid.nodes.sysid_node\n'
            'from galvo_sysid import BLAS_THREAD_VARIABLES as names\n'
            'print([os.environ.get(v) for v in names])\n')
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True, timeout=60, env=env).stdout.splitlines()
    assert out == ['False', "['1', '1', '1']"]
    env['OMP_NUM_THREADS'] = '2'  # a setting of the user's wins
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True, timeout=60, env=env).stdout.splitlines()
    assert out[-1] == "['1', '2', '1']"
