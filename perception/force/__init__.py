"""The bubble as a force sensor: contact wrench and slip from depth, dots and pressure.

* :mod:`~perception.force.features`: one bubble's contact in numbers (pressed area and
  volume against the free bubble, the dots' tangential displacement in metres over the
  patch, its core and its edge, the torsion, the pressure).
* :mod:`~perception.force.estimators`: the wrench from those features, by a physics
  model (normal force = gauge pressure times area; tangential = a stiffness times the
  patch's area times the dots' shift) or by a ridge regressor on the same inputs;
  both calibrated per rig (:mod:`~perception.force.calibration`).
* :mod:`~perception.force.slip`: slip onset per bubble (the patch's edge first, then
  the whole patch) and slip speed.
* :mod:`~perception.force.reflex`: a grip-force reflex on slip, bounded per object.

No sockets here: the ``wrench`` and ``slip`` nodes wire these to ports (docs/force.md).
"""
