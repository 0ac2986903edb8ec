"""`make demo`: a first live exchange of galvo_sysid messages between two processes.

A child process publishes the paper's reference model (Table I) as a ``ModalParameters``
message; this process subscribes over Fast DDS and prints what it received.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

__all__ = ['main']

_PUBLISHER = """
import time, rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy, DurabilityPolicy
from galvo_sysid_msgs.msg import ModalParameters
from galvo_sysid.plant import REFERENCE_MODEL as m
rclpy.init()
node = rclpy.create_node('demo_publisher')
qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
pub = node.create_publisher(ModalParameters, 'galvo/modal_parameters', qos)
pub.publish(ModalParameters(k0=m.k0, residues=list(m.residues), moves=100,
                            natural_frequencies=list(m.natural_frequencies),
                            damping_ratios=list(m.damping_ratios), fit_percent=100.0))
end = time.monotonic() + 15
while time.monotonic() < end and pub.get_subscription_count() == 0:
    rclpy.spin_once(node, timeout_sec=0.05)
time.sleep(0.5)
node.destroy_node()
rclpy.shutdown()
"""


def main() -> int:
    """Run the demo; return the process exit code."""
    import rclpy
    from galvo_sysid_msgs.msg import ModalParameters
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    child = subprocess.Popen([sys.executable, '-c', _PUBLISHER])
    got: list[ModalParameters] = []
    rclpy.init()
    node = rclpy.create_node('demo_subscriber')
    qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_subscription(ModalParameters, 'galvo/modal_parameters', got.append, qos)
    end = time.monotonic() + 20
    while not got and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.1)
    node.destroy_node()
    rclpy.shutdown()
    child.wait(timeout=20)
    if not got:
        print('demo: no message arrived from the publisher process', file=sys.stderr)
        return 1
    msg = got[0]
    print('Received /galvo/modal_parameters from another process over ROS 2 (Fast DDS):')
    print(f'  rigid body   k0 = {msg.k0:.4g}')
    for i, (k, w, z) in enumerate(zip(msg.residues, msg.natural_frequencies,
                                      msg.damping_ratios, strict=True), start=1):
        print(f'  mode {i}: k{i} = {k:+.4g}  omega_{i} = {w:.4g} rad/s  zeta_{i} = {z:.4g}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
