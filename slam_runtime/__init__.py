"""Runtime SLAM filters that load detector profiles.

Must never import ``calib``: a filter takes arrays and a detection model.

Done: motion models (odometry increments, unicycle, Ackermann), the
range-bearing measurement model, OSPA/GOSPA and trajectory metrics, and
RB-PHD-SLAM (``rbphd``) with its log runner (``run``), settings (``config``),
run folders (``report``) and Monte Carlo sweeps (``sweep``). Not yet:
delta-GLMB-SLAM and planar 3D features.
"""
