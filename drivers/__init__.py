"""Instrument drivers: ND 287 encoder display, AED torque amplifier, CiA 402 loader (CANopen, Modbus).

Each driver implements one protocol of ``drivers.base`` (AngleSource, TorqueSource, Loader) and registers under
the name bench configs use (``drivers.registry``): ``nd287``, ``aed``, ``cia402-canopen``, ``cia402-modbus``,
and ``virtual`` (in-process simulated bench). Drivers are synchronous with timeouts, reconnect a bounded
number of times, and raise one exception type per failure, naming the instrument. A driver instance serves one
caller at a time (the acquisition layer serialises access to each instrument).
"""
