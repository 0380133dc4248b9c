"""Runtime SLAM filters that load detector profiles (RB-PHD-SLAM, delta-GLMB-SLAM).

Must never import ``calib``: a filter takes arrays and a detection model.
"""
