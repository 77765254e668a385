"""Calibrating a real rig: the calibration file (:mod:`.rigfile`), the mount solve from
grasps of a known cylinder (:mod:`.mount`) and the procedure a lab runs (:mod:`.procedure`).
"""
