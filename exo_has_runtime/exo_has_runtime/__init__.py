"""What exo_has's nodes share beyond rclpy: how they spin, record, replay, time and run.

Node code imports ROS 2 itself (``import rclpy``, ``from exo_has_msgs.msg import HasState``);
this package holds the pieces ROS 2 does not provide the way the exoskeleton needs them:
:mod:`~exo_has_runtime.execution` (the executor and every node's ``main``), the DDS transport,
node parameters (:mod:`~exo_has_runtime.node_parameters`), the recorder and replay, period
timing, real-time priority, QoS profiles, and the supervision of node processes
(:mod:`~exo_has_runtime.processes`, :mod:`~exo_has_runtime.tether`). What needs no rclpy (joint
and topic names, the bag format, the parameters-file reader) is :mod:`exo_has_common`'s.
"""
