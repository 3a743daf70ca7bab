"""What a person can tell apart in force: the force discrimination threshold (JND) a model's
error is judged by. The seed paper's step: 10% of the force at or above 0.5 N, 25% below.

The accuracy bench and the reference (`analysis.verification`), the plate-spring's calibration
residuals (`sim.calibrate`), the JND lines of the plots and the synthetic observer's population
values (`studyctl.synthetic.observer`) all read it here.
"""

from __future__ import annotations

import numpy as np

FORCE_STEP_N = 0.5  # N: where the threshold steps
FORCE_WEBER = 0.10  # relative JND at or above the step: the seed paper; Allin et al. 2002 (about 10%)
FORCE_WEBER_LOW = 0.25  # relative JND below the step: the seed paper's


def force_jnd(force: np.ndarray) -> np.ndarray:
    """The relative force JND at each force (N): `FORCE_WEBER` at or above `FORCE_STEP_N`,
    `FORCE_WEBER_LOW` below."""
    return np.where(force >= FORCE_STEP_N, FORCE_WEBER, FORCE_WEBER_LOW)
