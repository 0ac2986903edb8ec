"""The nodes' small framework: descriptors of the one parameter list, no DDS."""

from __future__ import annotations

import sys
from pathlib import Path

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


def test_starting_a_node_bounds_dds_memory_unless_the_user_configured_fast_dds() -> None:
    """galvo_sysid.nodes points Fast DDS to the packaged reader defaults (DYNAMIC memory)."""
    import os
    import subprocess
    import sys
    import xml.etree.ElementTree as ET

    from galvo_sysid import FASTDDS_DEFAULTS

    names = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'RMW_FASTRTPS_USE_QOS_FROM_XML',
             'RMW_IMPLEMENTATION')
    code = ('import os\n'
            'import galvo_sysid.nodes\n'
            f'print([os.environ.get(v) for v in {names[:2]!r}])\n')
    base = {k: v for k, v in os.environ.items() if k not in names}

    def run(**extra: str) -> str:
        return subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                              check=True, timeout=60, env={**base, **extra}).stdout.strip()

    assert run() == repr([str(FASTDDS_DEFAULTS), '1'])
    assert run(FASTRTPS_DEFAULT_PROFILES_FILE='/mine.xml') == "['/mine.xml', None]"
    assert run(RMW_FASTRTPS_USE_QOS_FROM_XML='0') == "[None, '0']"
    assert run(RMW_IMPLEMENTATION='rmw_cyclonedds_cpp') == '[None, None]'
    # the packaged file is installed with the package and says what the docs say
    ns = {'d': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}
    reader = ET.parse(FASTDDS_DEFAULTS).getroot().find('d:profiles/d:data_reader', ns)
    assert reader is not None
    assert reader.get('is_default_profile') == 'true'
    assert reader.findtext('d:historyMemoryPolicy', namespaces=ns) == 'DYNAMIC'


def _spin_until_the_context_dies(fail_on_live: bool) -> int:
    """run_node with a spin that fails as rclpy's does when a signal shut the context down
    while its KeyboardInterrupt was lost in a finaliser (or, ``fail_on_live``, without)."""
    import pytest
    import rclpy
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
    from rclpy.node import Node

    def spin(node: Node, **_: object) -> None:
        if not fail_on_live:
            rclpy.shutdown()
        raise _rclpy.RCLError('failed to initialize wait set: the given context is not valid')

    monkey = pytest.MonkeyPatch()
    monkey.setattr(framework, 'spin', spin)
    try:
        return framework.run_node(lambda: Node('galvo_test_dead_context'), args=[])
    finally:
        monkey.undo()


def test_a_spin_failing_on_a_shut_down_context_is_a_clean_stop() -> None:
    import pytest
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

    assert _spin_until_the_context_dies(fail_on_live=False) == 0
    with pytest.raises(_rclpy.RCLError):  # on a live context the error is not swallowed
        _spin_until_the_context_dies(fail_on_live=True)


def test_a_stop_that_hangs_prints_every_threads_stack(tmp_path: Path) -> None:
    """run_node in a process of its own: the node's close takes longer than
    STOP_REPORT_AFTER (shortened), so the stacks go to stderr and the stop still ends."""
    import subprocess
    import textwrap

    script = textwrap.dedent("""
        import time
        import rclpy
        from rclpy.node import Node
        from galvo_sysid.nodes import framework
        framework.STOP_REPORT_AFTER = 0.2

        class Slow(Node):
            def close(self):
                time.sleep(1.0)  # a hung stop

        def spin(node, **_):
            rclpy.shutdown()  # as Ctrl-C does

        framework.spin = spin
        raise SystemExit(framework.run_node(lambda: Slow('galvo_test_slow_stop'), args=[]))
    """)
    out = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                         timeout=60, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert 'Timeout (0:00:00.200000)!' in out.stderr
    assert 'in close' in out.stderr  # the hung frame is named


def test_a_quick_stop_prints_nothing(tmp_path: Path) -> None:
    import subprocess
    import textwrap

    script = textwrap.dedent("""
        import rclpy
        from rclpy.node import Node
        from galvo_sysid.nodes import framework

        def spin(node, **_):
            rclpy.shutdown()

        framework.spin = spin
        raise SystemExit(framework.run_node(lambda: Node('galvo_test_quick_stop'), args=[]))
    """)
    out = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                         timeout=60, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert 'Timeout' not in out.stderr


def test_sigusr1_prints_the_stacks_of_a_running_node(tmp_path: Path) -> None:
    """``kill -USR1`` on a node that spins (here: a spin that sleeps) prints every thread's
    stack, and the node goes on to stop cleanly."""
    import signal
    import subprocess
    import textwrap
    import time

    script = textwrap.dedent("""
        import time
        import rclpy
        from rclpy.node import Node
        from galvo_sysid.nodes import framework

        def spin(node, **_):
            print('spinning', flush=True)
            time.sleep(3.0)  # a hang somewhere in the spin
            rclpy.shutdown()

        framework.spin = spin
        raise SystemExit(framework.run_node(lambda: Node('galvo_test_usr1'), args=[]))
    """)
    proc = subprocess.Popen([sys.executable, '-c', script], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == 'spinning'
    time.sleep(0.3)
    proc.send_signal(signal.SIGUSR1)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert 'in spin' in err
    assert 'Current thread' in err


def test_a_shutdown_whose_wake_up_is_lost_still_ends_the_spin() -> None:
    """rclpy's Ctrl-C handling wakes the executor, then shuts the context down from another
    thread; an executor that woke in between waits again with no one to wake it (rclpy.spin
    then hangs: seen in CI). Here the context is shut down without any wake-up at all, as
    that thread does, and the spin must still end within a few of its bounded waits."""
    import threading
    import time

    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node

    context = Context()
    rclpy.init(args=[], context=context)
    node = Node('galvo_test_lost_wake', context=context)
    ended = threading.Event()

    def run() -> None:
        framework.spin(node, wake=0.2)
        ended.set()

    spinner = threading.Thread(target=run, daemon=True)
    spinner.start()
    try:
        time.sleep(0.5)
        assert spinner.is_alive()  # a live context: the spin goes on
        assert context.handle is not None
        context.handle.shutdown()  # rcl_shutdown: no Python callback, no executor wake-up
        assert ended.wait(5.0), 'the spin did not notice the shut-down context'
    finally:
        node.destroy_node()
        context.destroy()
