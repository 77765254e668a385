"""Turning messages into pictures: Rerun logging, Foxglove export and video mosaics.

``viz.shapes`` builds triangle meshes of the known objects and places the cameras;
``viz.rerun_log`` logs messages as Rerun archetypes; ``viz.foxglove_export`` converts
them to Foxglove's well-known schemas; ``viz.mosaic`` draws the OpenCV mosaic of a video
frame. ``viz`` imports only ``messages`` and ``geometry``: it takes decoded messages, so
the viewer node and the bag commands (``cli.bagview``, which reads the bags) share it.
"""
