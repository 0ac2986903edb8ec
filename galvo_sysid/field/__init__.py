"""Field work: bags, offline identification, simulate-to-bag, live record/replay/echo, plots.

- :mod:`~galvo_sysid.field.bags`: reading and writing rosbag2 bags (reader, writer, message
  definitions, errors);
- :mod:`~galvo_sysid.field.offline`: identification of a bag, as the sysid node does it;
- :mod:`~galvo_sysid.field.results`: what identifying a bag gives (windows, pooled estimate,
  moves set aside);
- :mod:`~galvo_sysid.field.pooling`: the pooled estimate (joint fit or inverse-variance);
- :mod:`~galvo_sysid.field.parameter_file`: node parameter files read as the nodes do;
- :mod:`~galvo_sysid.field.jobs`: the fit processes worth starting;
- :mod:`~galvo_sysid.field.simulate`: bags straight from the simulator;
- :mod:`~galvo_sysid.field.commission`: a healthy scanner's model file from a bag;
- :mod:`~galvo_sysid.field.live`: record, replay and echo on the live ROS 2 graph (rclpy);
- :mod:`~galvo_sysid.field.plots`: Bode and trend figures;
- :mod:`~galvo_sysid.field.demo`: ``make demo``, the three nodes live.
"""
