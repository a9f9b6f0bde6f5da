"""Sensor models of the simulated bench: the torque transducer chain and the angle encoder.

Each model draws its noise from its own numpy Generator, so the result of a run does not depend on how the
clock is cut into batches.
"""

from __future__ import annotations

import numpy as np


class TorqueSensorModel:
    """Torque reading = gain·torque + zero offset − tare + white noise (N·m)."""

    def __init__(self, rng: np.random.Generator, noise_nm: float = 0.0, gain: float = 1.0, offset_nm: float = 0.0):
        self.rng, self.noise_nm, self.gain, self.offset_nm = rng, float(noise_nm), float(gain), float(offset_nm)
        self.tare_nm = 0.0

    def read(self, torque_nm: np.ndarray) -> np.ndarray:
        out = self.gain * np.asarray(torque_nm, dtype=float) + (self.offset_nm - self.tare_nm)
        if self.noise_nm > 0.0:
            out = out + self.noise_nm * self.rng.standard_normal(out.shape)
        return out


class EncoderModel:
    """Encoder reading (arcsec): angle + interpolation error over one signal period + noise, quantised.

    The interpolation error is a sinusoid of the given amplitude with the signal period (72″ for 18 000 lines).
    """

    def __init__(self, rng: np.random.Generator, noise_arcsec: float = 0.0, resolution_arcsec: float = 0.0,
                 signal_period_arcsec: float = 72.0, interpolation_error_arcsec: float = 0.0):
        self.rng = rng
        self.noise_arcsec = float(noise_arcsec)
        self.resolution_arcsec = float(resolution_arcsec)
        self.signal_period_arcsec = float(signal_period_arcsec)
        self.interpolation_error_arcsec = float(interpolation_error_arcsec)

    def read(self, angle_arcsec: np.ndarray) -> np.ndarray:
        out = np.asarray(angle_arcsec, dtype=float)
        if self.interpolation_error_arcsec > 0.0:
            out = out + self.interpolation_error_arcsec * np.sin(2.0 * np.pi * out / self.signal_period_arcsec)
        if self.noise_arcsec > 0.0:
            out = out + self.noise_arcsec * self.rng.standard_normal(out.shape)
        if self.resolution_arcsec > 0.0:
            out = np.round(out / self.resolution_arcsec) * self.resolution_arcsec
        return out
