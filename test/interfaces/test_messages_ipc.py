"""A ModalParameters message travels from one process to another over real rclpy/Fast DDS."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time

import rclpy
from galvo_sysid_msgs.msg import ModalParameters
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

PUBLISHER = textwrap.dedent("""
    import time, rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy, DurabilityPolicy
    from galvo_sysid_msgs.msg import ModalParameters
    rclpy.init()
    node = rclpy.create_node('ipc_test_publisher')
    qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pub = node.create_publisher(ModalParameters, 'ipc_test/modal_parameters', qos)
    msg = ModalParameters(window_index=7, target_angle=0.3, moves=100, k0=3.564e6,
                          residues=[2.069e6, -5.485e6, -4.604e5],
                          natural_frequencies=[7.108e4, 1.193e5, 1.674e5],
                          damping_ratios=[6.218e-3, 7.723e-3, 4.579e-3], fit_percent=99.5)
    pub.publish(msg)
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and pub.get_subscription_count() == 0:
        rclpy.spin_once(node, timeout_sec=0.05)
    time.sleep(1.0)
    pub.wait_for_all_acked()
    node.destroy_node()
    rclpy.shutdown()
""")


def test_modal_parameters_cross_process() -> None:
    proc = subprocess.Popen([sys.executable, '-c', PUBLISHER])
    received: list[ModalParameters] = []
    rclpy.init()
    try:
        node = rclpy.create_node('ipc_test_subscriber')
        qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(ModalParameters, 'ipc_test/modal_parameters',
                                 received.append, qos)
        deadline = time.monotonic() + 30
        while not received and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        # The publisher waits for this reader's acknowledgement: keep the reader until it
        # is done (a reader gone first leaves it waiting for the reader's lease to expire).
        while proc.poll() is None and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
        node.destroy_node()
    finally:
        rclpy.shutdown()
        proc.wait(timeout=30)
    assert proc.returncode == 0
    assert received, 'no ModalParameters message arrived from the other process'
    msg = received[0]
    assert msg.window_index == 7
    assert msg.moves == 100
    assert list(msg.natural_frequencies) == [7.108e4, 1.193e5, 1.674e5]
