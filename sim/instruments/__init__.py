"""Protocol simulators of the bench instruments, all driven by one shared physics state and clock.

- ``physics.SharedPhysics``: the simulated bench (``sim.bench.SimulatedBench`` or any object with the same
  contract) behind a lock, advanced in real time × speed by a ticker thread or stepped by hand in tests.
- ``nd287.ND287Server`` and ``aed.AEDServer``: asyncio TCP servers (drivers open ``socket://127.0.0.1:<port>``).
- ``drive402.Drive402Model``: one CiA 402 drive (state machine, profile torque, safety) with two front ends,
  ``drive_modbus`` (pymodbus server, TCP or RTU framing) and ``drive_canopen`` (canopen LocalNode).
- ``socketcand_hub.SocketcandHub``: a loopback socketcand server so CANopen works across processes.
- ``serve.InstrumentSimulators``: all of the above on one event loop (what ``tcms sim serve`` runs).

Every server binds 127.0.0.1 unless told otherwise; port 0 picks an ephemeral port.
"""
