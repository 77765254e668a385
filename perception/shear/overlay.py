"""The overlay the viewer shows: IR with the flow field and the mean-shear arrow."""

from __future__ import annotations

import math

import cv2
import numpy as np

from perception.shear.flow import stretch_ir
from perception.shear.tracker import ShearResult


def draw_overlay(
    ir: np.ndarray,
    result: ShearResult,
    *,
    step_px: int = 12,
    arrow_gain: float = 10.0,
    flow_gain: float = 2.0,
) -> np.ndarray:
    """IR with the flow field and the summed arrow, as in the paper's handover figure.

    Args:
        ir: full-resolution IR image.
        result: an estimate from :meth:`ShearTracker.update` with ``keep_fields=True``
            (without fields only the summed arrow is drawn).
        step_px: grid spacing of the small flow arrows (full-resolution pixels).
        arrow_gain: length of the summed arrow per pixel of mean shear.
        flow_gain: the small arrows are the flow scaled by this (sub-pixel flow is
            invisible at scale 1).

    Returns:
        uint8 BGR ``(h, w, 3)`` image.
    """
    valid = (ir > 0) & (ir < 65535)
    bgr = cv2.cvtColor(stretch_ir(ir, valid), cv2.COLOR_GRAY2BGR)
    h, w = ir.shape
    if result.flow is not None and result.mask is not None:
        fh, fw = result.flow.shape[:2]
        sx, sy = w / fw, h / fh
        for y in range(step_px // 2, h, step_px):
            for x in range(step_px // 2, w, step_px):
                fy_i, fx_i = min(int(y / sy), fh - 1), min(int(x / sx), fw - 1)
                if not result.mask[fy_i, fx_i]:
                    continue
                dx, dy = result.flow[fy_i, fx_i]
                if not (math.isfinite(dx) and math.isfinite(dy)):
                    continue
                end = (int(round(x + dx * sx * flow_gain)), int(round(y + dy * sy * flow_gain)))
                cv2.arrowedLine(bgr, (x, y), end, (0, 255, 0), 1, tipLength=0.3)
    centre = (w // 2, h // 2)
    if result.has_reference:
        vector = result.shear_px * arrow_gain
        end = (int(round(centre[0] + vector[0])), int(round(centre[1] + vector[1])))
        color = (0, 0, 255) if result.direction_defined else (128, 128, 128)
        cv2.arrowedLine(bgr, centre, end, color, 2, tipLength=0.25)
        cv2.circle(bgr, centre, 3, color, -1)
    return bgr
