"""Identifiability of a fitted model's terms: two terms that cancel are not both named (pure numpy).

Two candidate terms whose forms nearly coincide over the data (two near-equal periods, a scale error against shaft
torsion, backlash against a cubic stiffness) can be fitted jointly with large, opposite contributions whose sum is a
small shape that neither of them is. Forward selection accepts such a pair when the sum fits; the pair then names
two effects that the data cannot tell apart, at sizes that are not physical.

A pair is *cancelling* when, in the joint fit on all rows, the RMS of the sum of the two (centred) contributions is
below ``CANCEL_RATIO`` of the larger one's. Each cancelling pair is resolved:

* keep the simpler explanation — the one term whose model without the other scores within one paired standard error
  of the pair in the same cross-validation folds (the smaller CV error; fewer parameters on a tie) — and reject the
  other with the reason; or
* when the pair is significantly better than either alone, name neither: an alias group (not in the model) with the
  experiment that separates them. What the pair fitted then stays in the residual, where the verdict and the
  localisation see it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tcms_daq.discrepancy import catalogue as cat
from tcms_daq.discrepancy.selection import Columns, CVScore, FittedModel, _canonical_corr, _design, cv_score

CANCEL_RATIO = 0.5


@dataclass(frozen=True)
class Cancellation:
    """Two terms of a joint fit whose contributions cancel."""

    names: tuple[str, str]
    sizes_arcsec: tuple[float, float]  # RMS of each term's contribution (centred)
    sum_arcsec: float  # RMS of their sum
    correlation: float  # canonical correlation of their columns given the rest of the model

    @property
    def ratio(self) -> float:
        return self.sum_arcsec / max(self.sizes_arcsec)

    def describe(self) -> str:
        a, b = self.names
        return (f"{a} and {b} cancel: {self.sizes_arcsec[0]:.3g}″ and {self.sizes_arcsec[1]:.3g}″ RMS that sum to "
                f"{self.sum_arcsec:.3g}″ (column correlation {self.correlation:.2f})")


def contributions(cols: Columns, model: FittedModel, rows: np.ndarray) -> dict[str, np.ndarray]:
    """Each term's contribution (″) to the model's prediction at ``rows``, centred (the offset absorbs means)."""
    out: dict[str, np.ndarray] = {}
    for name, a, b in model.where:
        c = cols.rows_of(name, model.nl.get(name), rows)
        v = c[:, 0] if cat.CATALOGUE[name].fixed_gain else c @ model.beta[a:b]
        out[name] = v - v.mean()
    return out


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else 0.0


def cancelling_pairs(cols: Columns, model: FittedModel, rows: np.ndarray) -> list[Cancellation]:
    """The model's cancelling pairs, strongest cancellation first."""
    parts = contributions(cols, model, rows)
    names = list(parts)
    found = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            sa, sb, s = _rms(parts[a]), _rms(parts[b]), _rms(parts[a] + parts[b])
            if max(sa, sb) <= 0 or s >= CANCEL_RATIO * max(sa, sb):
                continue
            rest = [n for n in names if n not in (a, b)]
            base, fixed, _ = _design(cols, rest, model.nl, rows)
            if np.any(fixed):
                base = np.column_stack((base, fixed))
            corr = _canonical_corr(cols.rows_of(a, model.nl.get(a), rows), cols.rows_of(b, model.nl.get(b), rows),
                                   base)
            found.append(Cancellation((a, b), (sa, sb), s, corr))
    return sorted(found, key=lambda c: c.ratio)


@dataclass(frozen=True)
class Resolution:
    """What to do with one cancelling pair: keep one (``keep``, ``drop``) or name neither (an alias group)."""

    cancellation: Cancellation
    keep: str | None
    drop: tuple[str, ...]
    reason: str


def resolve(cols: Columns, y: np.ndarray, folds: list[tuple[np.ndarray, np.ndarray]], names: list[str],
            cancellation: Cancellation) -> Resolution:
    """Keep the simpler explanation of a cancelling pair when it predicts as well (within one paired SE), else
    neither (an alias group)."""
    a, b = cancellation.names
    both = cv_score(cols, y, folds, names)
    alone: dict[str, CVScore] = {keep: cv_score(cols, y, folds, [n for n in names if n != other])
                                 for keep, other in ((a, b), (b, a))}

    def n_params(name: str) -> int:
        return len(cat.CATALOGUE[name].parameters)

    best = min(alone, key=lambda k: (alone[k].mse, n_params(k)))
    diff = alone[best].fold_mse - both.fold_mse
    se = float(np.std(diff, ddof=1) / math.sqrt(len(diff))) if len(diff) > 1 else 0.0
    what = cancellation.describe()
    if diff.mean() <= se:
        other = b if best == a else a
        return Resolution(cancellation, best, (other,),
                          f"{what}; {best} alone predicts as well (held-out RMS {alone[best].rms:.3g}″ against "
                          f"{both.rms:.3g}″ with both): the simpler explanation is kept")
    return Resolution(cancellation, None, (a, b),
                      f"{what}; together they predict better (held-out RMS {both.rms:.3g}″ against "
                      f"{alone[best].rms:.3g}″ with {best} alone), but the data cannot tell their sizes apart: "
                      f"neither is named")
