"""TCMS-DAQ: torsional characteristic measurement of precision robot reducers.

The core (units, config, samples, compensation, analysis, discrepancy) is pure numpy; drivers, acquisition and
the service are thin shells around it (docs/architecture.md).
"""

__version__ = "0.1.0"
