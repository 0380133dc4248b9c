"""Sensor-log readers and writers; :func:`calib.io.registry.read_log` picks one from the path."""
