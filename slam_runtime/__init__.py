"""Runtime SLAM filters that load detector profiles (RB-PHD-SLAM, delta-GLMB-SLAM).

Must never import ``calib``: a filter takes arrays and a detection model.

State: motion models, the measurement model, OSPA/GOSPA and trajectory
metrics are done and tested. RB-PHD-SLAM (``rbphd``, ``run``) is implemented
and its map update is tested on known scenarios, but on the small simulated
park its trajectory is still worse than odometry alone (the static clutter of
bushes is mapped as features, and the particle weighting needs work), so it is
not in the CLI yet.
"""
