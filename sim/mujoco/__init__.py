"""The second world: the bubbles as pressurised MuJoCo shells (docs/mujoco.md).

``sim.mujoco.mesh`` builds the membrane's cap mesh, ``sim.mujoco.model`` the MJCF,
``sim.mujoco.physics`` steps it with the air's gas law and reads the contact wrenches,
``sim.mujoco.world`` runs a scene on it frame by frame (the face of ``sim.world.World``),
``sim.mujoco.render`` ray-casts a camera's view of a deformed membrane.

Imported only by what needs MuJoCo: ``import sim`` does not load it.
"""
