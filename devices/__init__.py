"""Protocol clients for the real hardware, pure Python (no runtime, no simulator).

* :mod:`devices.wsg50`: the Schunk WSG 50's binary TCP protocol (frames, CRC, status
  codes) and a client with timeouts, streamed state and reconnection.
* :mod:`devices.mcp2221` and :mod:`devices.abp`: a Honeywell ABP pressure sensor
  read over I2C through a Microchip MCP2221A USB bridge, with pyusb.
* :mod:`devices.royale`: frames of a PMD pico flexx (royale SDK) as ``ToFImage``.
* :mod:`devices.base`: ``Device``, the lifecycle the clients share (``connect``,
  ``disconnect``, ``is_connected``, a ``with`` block).

Nodes wrap these; tests drive them against emulators (``sim.wsg50_server``, an
emulated pyusb backend, a stand-in for the royale SDK). docs/devices.md has the facts.
"""
