"""Proximity pose estimation (paper, "Proximity Pose Estimation") and its baselines.

- ``common``: the problem (``object_from_tool``, the paper's G X T), results,
  observability, seeds and error metrics.
- ``lm``: Levenberg-Marquardt on SE(3) (fast path).
- ``ipopt``: the paper's formulation with CasADi and IPOPT.
- ``icp``: point-to-point ICP against a sampled model surface (baseline).
- ``estimator``: seeding, tracking, wrong-minimum detection and recovery around any of them.
- ``synthetic``: two-bubble grasp clouds of a known object at a known pose.
"""

from __future__ import annotations

from perception.pose.common import FitResult
from perception.pose.estimator import EstimatorParams, PoseEstimator
from perception.pose.lm import LMParams, LMSolver

__all__ = ["EstimatorParams", "FitResult", "LMParams", "LMSolver", "PoseEstimator"]
