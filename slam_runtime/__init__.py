"""Runtime SLAM filters that load detector profiles (RB-PHD-SLAM, delta-GLMB-SLAM).

Must never import ``calib``: a filter takes arrays and a detection model.

State: motion models, the measurement model, OSPA/GOSPA and trajectory
metrics are done and tested. RB-PHD-SLAM (``rbphd``, ``run``) is implemented
and its map update is tested on known scenarios, but it is not yet tuned on
the simulated park, Victoria Park or UTIAS and is not in the CLI.
"""
