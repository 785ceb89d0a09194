"""Constants of the simulated Kinect shared by :mod:`sim.kinect` and its compiled kernels.

Kept apart so that the kernels (:mod:`sim._kinect_kernels`, numba) and the documented pure functions
(:mod:`sim.kinect`) read the same numbers without importing each other.
"""

from __future__ import annotations

import math

# The angle terms of both noise models have a pole at 90 deg (at 85 deg the v2 model already gives
# ~10 cm); the papers fitted them on measurements well short of grazing incidence, so the angle is held
# at 75 deg instead of extrapolating toward the pole (an assumption of this simulation, not paper data).
THETA_MAX = math.radians(75.0)

#: Kinect v1 disparity step: f = 580 px, baseline 7.5 cm, disparity in 1/8 px.
KINECT1_FOCAL_PX, KINECT1_BASELINE_M, KINECT1_SUBPIXEL = 580.0, 0.075, 8.0

#: Codes of the noise models and output quantisations, as the compiled kernels take them.
NGUYEN2012, FANKHAUSER2015 = 0, 1
QUANT_NONE, QUANT_MM, QUANT_DISPARITY = 0, 1, 2
NOISE_CODES = {"nguyen2012": NGUYEN2012, "fankhauser2015": FANKHAUSER2015}
QUANT_CODES = {None: QUANT_NONE, "mm": QUANT_MM, "disparity": QUANT_DISPARITY}
