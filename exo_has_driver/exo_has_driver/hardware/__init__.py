"""The hardware side of the driver, free of ROS: the CANopen master and its parts.

- :mod:`.units`: SI against drive and sensor board units, sensor checks;
- :mod:`.cia402`: which controlword moves a drive toward the wanted CiA 402 state;
- :mod:`.sdo`: a small blocking SDO client for the configuration at start;
- :mod:`.bus`: opening the python-can bus, reading its faults;
- :mod:`.config`: the master's settings, its samples and the valve mode inference;
- :mod:`.frames`: the master's CANopen frames, built and read as pure functions;
- :mod:`.records`: what the master tracks of each slave and joint;
- :mod:`.startup`: start-up of the slaves over NMT and SDO (identity, PDO configuration);
- :mod:`.receiver`: the slaves' frames, decoded into the records and completed into samples;
- :mod:`.supervision`: the faults that hold, the stop latch they set, and the reset;
- :mod:`.master`: the master (its I/O thread and the SYNC cycle).
"""
