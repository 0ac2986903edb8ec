"""Online monitoring without ROS.

Pairing moves into windows, drift verdicts, the task objects the nodes wire.
"""
