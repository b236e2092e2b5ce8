"""The hardware side of the driver, free of ROS: the CANopen master and its parts.

- :mod:`.units`: SI against drive and sensor board units, sensor checks;
- :mod:`.cia402`: which controlword moves a drive toward the wanted CiA 402 state;
- :mod:`.sdo`: a small blocking SDO client for the configuration at start;
- :mod:`.bus`: opening the python-can bus, reading its faults;
- :mod:`.master`: the master (NMT, SDO configuration, SYNC cycle, PDOs, heartbeats, EMCY,
  supervision and the stop latch).
"""
