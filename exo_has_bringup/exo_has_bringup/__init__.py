"""The running of the whole exoskeleton: session plans, their processes, the demo and its report.

A session is planned without ROS (:mod:`~exo_has_bringup.plan`: which nodes, their
parameters, how they are composed into processes) and run by :mod:`~exo_has_bringup.runner`,
on this host or on two virtual hosts joined by a link (:mod:`~exo_has_bringup.hosts`).
``exo-has demo`` (:mod:`~exo_has_bringup.demo`) runs one and writes its report
(:mod:`~exo_has_bringup.analysis`, :mod:`~exo_has_bringup.report`).
"""
