"""Topic names and message conversions.

Between ROS messages and plain values.
"""
