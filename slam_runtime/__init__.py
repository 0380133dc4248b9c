"""RFS SLAM at run time: what a robot embeds.

Takes arrays, models and a detector profile object (loaded by ``profiles``) and
returns results; it never imports ``calib``, pandas, matplotlib or Dask, and
writes no files (the ``detcal`` application writes run folders).

The seam every filter shares (see the README's architecture section):

* ``particles`` -- resamplers (free functions taking a Generator) and the
  particle history (states and an ancestry; resampling cost independent of the
  log's length);
* ``vehicle`` -- vehicle models (odometry increments with a constant noise
  term, unicycle, Ackermann with a steering offset), sampled over particles;
* ``features`` -- feature models (range-bearing point landmarks): predict z and
  H, inverse for birth, innovation with angle wrapping;
* ``mapfilter`` -- the map-filter interface ``update(maps, poses, measurements)
  -> (maps, log-likelihood per particle)``; ``rbphd`` is its RB-PHD
  implementation on Gaussian mixtures of all particles (``gm``);
* ``slam`` -- the Rao-Blackwellised particle loop; ``sources`` -- measurement
  sources per kind of log and the controls; ``config`` -- settings and the
  factory; ``run`` -- run and evaluate; ``metrics`` -- OSPA/GOSPA and
  trajectory RMSE.
"""
