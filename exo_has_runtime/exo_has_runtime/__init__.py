"""What exo_has's nodes share beyond rclpy: how they spin, record, replay, time and run.

Node code imports ROS 2 itself (``import rclpy``, ``from exo_has_msgs.msg import HasState``);
this package holds the pieces ROS 2 does not provide the way the exoskeleton needs them:
:mod:`~exo_has_runtime.execution` (the executor and every node's ``main``), the recorder and the
bag tools, replay, period timing, real-time priority, topic names and QoS profiles, and the
launch-free process helpers of the tests (:mod:`~exo_has_runtime.testing`).
"""
