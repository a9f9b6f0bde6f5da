"""Instrument drivers: ND 287 encoder display, AED torque amplifier, CiA 402 loader (CANopen, Modbus)."""
