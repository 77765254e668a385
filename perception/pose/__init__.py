"""Proximity pose estimation (paper, "Proximity Pose Estimation") and its baselines.

- ``problem``: the problem (``object_from_tool``, the paper's G X T), results, input
  checks, residuals and observability.
- ``cloud``: finite rows, subsampling, the noise measured from the cloud and the camera
  rays it lies along.
- ``seeds``: cold-start seeds from the data and the turns of a minimum.
- ``symmetry``: the object's symmetry turns and the distance between two estimates.
- ``judge``: the uncertainty of an estimate and what the verdict compares with it.
- ``metrics``: the errors benches and tests score estimates with (right, covered).
- ``lm``: Levenberg-Marquardt on SE(3) (fast path).
- ``ipopt``: the paper's formulation with CasADi and IPOPT.
- ``icp``: point-to-point ICP against a sampled model surface (baseline).
- ``estimator``: seeding, tracking, wrong-minimum detection and recovery around any of them;
  ``params``: its knobs.
- ``synthetic``: two-bubble grasp clouds of a known object at a known pose.
"""

from __future__ import annotations

from perception.pose.estimator import PoseEstimator
from perception.pose.lm import LMParams, LMSolver
from perception.pose.params import EstimatorParams
from perception.pose.problem import FitResult

__all__ = ["EstimatorParams", "FitResult", "LMParams", "LMSolver", "PoseEstimator"]
