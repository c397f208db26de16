"""`uwb-hil calibrate`: the simulator's measurement errors next to the real recordings in ../shared/data.

Real error = measured - geometric truth (UTIL: the tag 0.0908 m above the Vicon pose; rcv_twr: anchors
moved by the source's antenna offset, read from the data README). Statistics are per trial (one flight file or
one simulated flight) and then averaged over trials, so no single file decides a number:

* UTIL TDoA groups: LOS TDoA2 (const1 + const2), LOS TDoA3 (const1), NLOS TDoA2 (const3). The simulated
  side flies the same constellations (antennas facing the centroid; UTIL has no orientations) on
  `random` campaign flights with take-off and landing at the real rates, profile "los" or "nlos".
  Per trial: mean, median, std (|e| < 1 m, as the data README measures), tail fractions |e| > 0.3 m and
  > 1 m (all samples), and the per-pair bias spread = std over anchor pairs of the pair's mean error
  (|e| < 1 m; pairs with >= 1 % of the trial's samples; a pair and its reverse are one pair).
* rcv_twr TWR: the simulator's error model evaluated at the recorded poses (same anchors and antenna
  orientations), and the error's dependence on azimuth/elevation of the tag seen from the anchor and of
  the anchor seen from the tag (binned medians, each link's median removed: the pose-dependent part).

Modules: stats.py (the statistics of one trial), util_tdoa.py (UTIL groups, real and simulated trials),
rcv_twr.py (rcv_twr ranges, the simulator at the same poses, pose dependence), plots.py, compare.py
(calibrate(): everything, as a dict), cli.py (the command: parses and prints).
"""
