"""Bags: rosbag2 directories (MCAP storage, metadata version 9) of CDR messages, without ROS.

One module per task: :mod:`.definitions` (message definitions and type hashes), :mod:`.qos`
(offered QoS as a bag records it), :mod:`.writer` (writing, flushed chunk by chunk),
:mod:`.reader` (reading and summaries), :mod:`.records` (an unfinished MCAP file read record by
record) and :mod:`.recovery` (a killed recording rewritten as a complete bag).
:mod:`exo_has_common.bag` gathers their public names and is the ``exo-has bag`` command.
"""
