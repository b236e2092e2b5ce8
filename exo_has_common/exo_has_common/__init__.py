"""What every exo_has package shares, free of rclpy: names, files and errors.

Joint names (:mod:`~exo_has_common.joints`), topic names (:mod:`~exo_has_common.topics`), the
reader of ROS parameters files (:mod:`~exo_has_common.params_yaml`), rosbag2 MCAP bags
(:mod:`~exo_has_common.bag`) and the root of every exo_has error
(:class:`~exo_has_common.errors.ExoHasError`). The physics (exo_has_sim) builds on this package
and on nothing that imports rclpy.
"""
