"""Monte Carlo propagation of distributions (JCGM 101) through the whole evaluation: the cross-check of the GUM
budgets of ``tcms_daq.uncertainty.budget``.

Each draw applies every declared Type B input at once (Gaussian, estimate 0, its standard uncertainty) to the
record and evaluates it; the budget's Type A line (the loop scatter and the noise bootstrap, ``record_type_a``),
which a draw cannot repeat, is added to each result as a scaled and shifted t-distribution with its degrees of
freedom (JCGM 101 6.4.9). The coverage interval is
the probabilistically symmetric 95 % interval of the results.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from tcms_daq.analysis.evaluation import Evaluation, EvaluationSettings
from tcms_daq.config.models import ChainUncertainty
from tcms_daq.uncertainty.budget import _evaluate, _noise_bootstrap, record_type_a, result_values
from tcms_daq.uncertainty.chain import chain_inputs


@dataclass(frozen=True)
class MonteCarloResult:
    """The distribution of one result: its mean, standard deviation and the 95 % probabilistically symmetric
    coverage interval [low, high] (half-width ``half_width``), over ``draws`` evaluations."""

    mean: float
    std: float
    low: float
    high: float
    draws: int

    @property
    def half_width(self) -> float:
        return 0.5 * (self.high - self.low)


def monte_carlo(time_s: npt.ArrayLike, torque_nm: npt.ArrayLike, angle_arcsec: npt.ArrayLike,
                settings: EvaluationSettings, chain: ChainUncertainty | None, nominal: Evaluation,
                draws: int = 400, seed: int = 0) -> dict[str, MonteCarloResult]:
    """JCGM 101 propagation of the declared chain (and the Type A line) through ``evaluate``; per result name."""
    t = np.asarray(time_s, dtype=float)
    torque0 = np.asarray(torque_nm, dtype=float)
    angle0 = np.asarray(angle_arcsec, dtype=float)
    rng = np.random.default_rng(seed)
    fixed = replace(settings, test_torque_nm=nominal.test_torque_nm)
    inputs = chain_inputs(chain, nominal.test_torque_nm) if chain is not None else []
    names = list(result_values(nominal))
    type_a = record_type_a(nominal, names, _noise_bootstrap(t, torque0, angle0, fixed, nominal, names))
    samples: dict[str, list[float]] = {name: [] for name in names}
    for _ in range(draws):
        torque, angle = torque0, angle0
        for inp in inputs:
            torque, angle = inp.apply(torque, angle, float(rng.normal(0.0, inp.u)))
        values = result_values(_evaluate(t, torque, angle, fixed))
        for name in names:
            u_a, dof = type_a[name].u, type_a[name].dof
            scatter = u_a * float(rng.standard_t(dof)) if u_a is not None and dof is not None else 0.0
            samples[name].append(values[name] + scatter)
    out = {}
    for name, vals in samples.items():
        arr = np.asarray(vals)
        low, high = np.quantile(arr, [0.025, 0.975])
        out[name] = MonteCarloResult(float(arr.mean()), float(arr.std(ddof=1)), float(low), float(high), arr.size)
    return out
