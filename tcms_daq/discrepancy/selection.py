"""Forward selection of catalogue effects, scored by blocked (grouped) cross-validation.

All fits are least squares of the residual r = measured − simulated on a constant offset plus the effects'
columns; ``time_skew`` and ``torque_zero_offset`` enter with gain 1 (their re-evaluated simulation is
subtracted from the target).
Nonlinear parameters (period, skew, torque offset) are chosen inside every training fold: a grid search of the
fold's residual (on at most ``SCAN_ROWS`` evenly strided training rows) refined by parabolic interpolation — a
fixed-gain term's best grid step scanned again finely on every training row, a free period beside the band left out
around the signal period scanned finely on its admissible side — then all linear coefficients are refitted jointly
on every training row. The selection itself runs on at most
``SELECT_ROWS`` evenly strided rows (densely sampled runs carry far more rows than the choice needs); the
final fit and the outer folds of the nested CV use every row.

Selection: greedy forward steps; a step's score is the leave-one-group-out CV RMS; the path is cut by the
1-SE rule and by a minimum practical gain. Candidates that score within one (paired) standard error of the
step's winner, also improve on the previous model and whose columns are strongly correlated with the
winner's form an alias group. A winner whose fitted value is implausible is excluded and the next one tried.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tcms_daq.crossval import leave_one_group_out
from tcms_daq.discrepancy import catalogue as cat
from tcms_daq.discrepancy.design import MIN_GROUPS, DesignData, block_groups
from tcms_daq.discrepancy.effects import sincos

SCAN_ROWS = 3000
SELECT_ROWS = 12000  # the selection runs on at most this many evenly strided rows
MAX_TERMS = 4
MIN_STEP_GAIN = 0.01  # continue the path while a step cuts the CV RMS by ≥ 1 %
MIN_GAIN = 0.03  # an accepted term must cut the CV RMS by ≥ 3 %
ALIAS_CORR = 0.9
FINE_POINTS = 9  # a fixed-gain term's best grid step is scanned again at this many points


class Columns:
    """Candidate columns on the full trace, computed once and shared by every fold and selection."""

    def __init__(self, data: DesignData):
        self.data = data
        n = len(data)
        self.select_stride = max(1, math.ceil(n / SELECT_ROWS))
        scan_stride = self.select_stride * max(1, math.ceil(n / self.select_stride / SCAN_ROWS))
        idx = np.arange(n)
        self.in_select = idx % self.select_stride == 0
        self.in_scan = idx % scan_stride == 0  # a subset of the selection rows
        self.scan_pos = np.cumsum(self.in_scan) - 1
        self._cols: dict[tuple[str, float | None], np.ndarray] = {}
        self._grids: dict[str, tuple[np.ndarray, dict[str, np.ndarray]]] = {}

    def rows_of(self, name: str, nl: float | None, rows: np.ndarray) -> np.ndarray:
        """Columns of ``name`` at ``rows``; linear ones are cached on the full trace."""
        if nl is not None and cat.CATALOGUE[name].nonlinear:
            return cat.columns_at(name, self.data, nl, rows)
        return self.get(name, nl)[rows]

    def get(self, name: str, nl: float | None = None) -> np.ndarray:
        key = (name, None if nl is None else float(nl))
        col = self._cols.get(key)
        if col is None:
            col = cat.columns(name, self.data, nl)
            if len(self._cols) > 256:
                self._cols = {k: v for k, v in self._cols.items() if k[1] is None}
            self._cols[key] = col
        return col

    def grid(self, name: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """(grid values, products on the scan rows): for a sinusoid S, C, SS, SC, CC; for a fixed-gain
        term D and DD; each of shape (m, n_scan), so a fold's sums are matrix–vector products."""
        g = self._grids.get(name)
        if g is None:
            values = cat.grid(name, self.data)
            if values is None:
                raise ValueError(f"effect {name!r} has no grid of nonlinear values")
            scan = np.flatnonzero(self.in_scan)
            if cat.CATALOGUE[name].fixed_gain:
                d = np.stack([cat.columns_at(name, self.data, float(v), scan)[:, 0] for v in values])
                prods = _stacked({"D": d, "DD": d * d})
            else:
                theta = self.data.sim_angle_arcsec[scan]
                x = (2.0 * math.pi / values)[:, None] * theta[None, :]
                sn, cs = np.sin(x), np.cos(x)
                prods = _stacked({"S": sn, "C": cs, "SS": sn * sn, "SC": sn * cs, "CC": cs * cs})
            g = (values, prods)
            self._grids[name] = g
        return g


Sums = dict[str, tuple[np.ndarray, np.ndarray]]


def _stacked(parts: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The product matrices stacked into one float32 block (one pass over memory per scan); ``_names`` and
    ``_m`` let :func:`_sums` split the result."""
    block = np.concatenate(list(parts.values()), axis=0).astype(np.float32)
    return {"_block": block, "_names": np.array(list(parts)), "_m": np.array(len(next(iter(parts.values()))))}


def _sums(prods: dict[str, np.ndarray], w: np.ndarray, wr: np.ndarray) -> Sums:
    """For every product P: (P @ w, P @ wr) as float64, from one matrix product."""
    if "_block" not in prods:
        return {k: (v @ w, v @ wr) for k, v in prods.items()}
    out = prods["_block"] @ np.column_stack((w, wr)).astype(np.float32)
    m = int(prods["_m"])
    return {str(k): (out[i * m:(i + 1) * m, 0].astype(float), out[i * m:(i + 1) * m, 1].astype(float))
            for i, k in enumerate(prods["_names"])}


def _design(cols: Columns, names: list[str], nl: dict[str, float], rows: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, list[tuple[str, int, int]]]:
    parts = [np.ones((len(rows), 1))]
    fixed = np.zeros(len(rows))
    where: list[tuple[str, int, int]] = []
    k = 1
    for name in names:
        c = cols.rows_of(name, nl.get(name), rows)
        if cat.CATALOGUE[name].fixed_gain:
            fixed += c[:, 0]
            where.append((name, k, k))
        else:
            parts.append(c)
            where.append((name, k, k + c.shape[1]))
            k += c.shape[1]
    return np.column_stack(parts), fixed, where


def _solve(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    g = x.T @ x
    b = x.T @ y
    d = np.sqrt(np.diag(g))
    d[d == 0] = 1.0
    gs = g / d[:, None] / d[None, :]
    gs[np.diag_indices_from(gs)] += 1e-12
    try:
        beta = np.linalg.solve(gs, b / d)
    except np.linalg.LinAlgError:
        beta = np.linalg.lstsq(gs, b / d, rcond=None)[0]
    return beta / d


def _parabolic(x: np.ndarray, s: np.ndarray, i: int) -> float:
    if i <= 0 or i >= len(x) - 1:
        return float(x[i])
    x0, x1, x2 = x[i - 1], x[i], x[i + 1]
    s0, s1, s2 = s[i - 1], s[i], s[i + 1]
    den = (x1 - x0) * (s1 - s2) - (x1 - x2) * (s1 - s0)
    if den == 0:
        return float(x1)
    xv = x1 - 0.5 * ((x1 - x0) ** 2 * (s1 - s2) - (x1 - x2) ** 2 * (s1 - s0)) / den
    return float(min(max(xv, min(x0, x2)), max(x0, x2)))


def scan_nonlinear(cols: Columns, name: str, residual: np.ndarray, train: np.ndarray) -> float:
    """Best nonlinear value of ``name`` for the training rows' residual (grid + parabolic refinement).

    Each grid value is scored by the residual sum of squares after fitting it (with an offset) to the
    residual of the model without it, on the strided scan rows that are training rows.
    """
    values, prods = cols.grid(name)
    w: np.ndarray | None = np.zeros(int(cols.in_scan.sum()))
    in_train = train[cols.in_scan[train]]
    scan_rows = np.flatnonzero(cols.in_scan)  # the rows of w and r
    if len(in_train) < 8:
        in_train = train
        w = None
    if w is None:  # tiny data: evaluate the grid on the training rows directly
        scan_rows = in_train
        r = residual[in_train]
        stack = np.stack([cat.columns_at(name, cols.data, float(v), in_train) for v in values])
        if cat.CATALOGUE[name].fixed_gain:
            d = stack[:, :, 0]
            prods = {"D": d, "DD": d * d}
        else:
            sn, cs = stack[:, :, 0], stack[:, :, 1]
            prods = {"S": sn, "C": cs, "SS": sn * sn, "SC": sn * cs, "CC": cs * cs}
        w = np.ones(len(in_train))
    else:
        pos = cols.scan_pos[in_train]
        w[pos] = 1.0
        r = np.zeros(len(w))
        r[pos] = residual[in_train]
    n = float(w.sum())
    wr = w * r
    r1, r2 = wr.sum(), float(wr @ r)
    sums = _sums(prods, w, wr)
    if cat.CATALOGUE[name].fixed_gain:
        (d_w, d_r), (dd_w, _) = sums["D"], sums["DD"]
        sse = r2 - 2.0 * d_r + dd_w - (r1 - d_w) ** 2 / n
    else:
        m = len(values)
        a = np.empty((m, 3, 3))
        a[:, 0, 0] = n
        a[:, 0, 1] = a[:, 1, 0] = sums["S"][0]
        a[:, 0, 2] = a[:, 2, 0] = sums["C"][0]
        a[:, 1, 1] = sums["SS"][0]
        a[:, 1, 2] = a[:, 2, 1] = sums["SC"][0]
        a[:, 2, 2] = sums["CC"][0]
        b = np.stack((np.full(m, r1), sums["S"][1], sums["C"][1]), axis=1)
        a[:, [0, 1, 2], [0, 1, 2]] += 1e-9 * (1.0 + a[:, [0, 1, 2], [0, 1, 2]])
        beta = np.linalg.solve(a, b[:, :, None])[:, :, 0]
        sse = r2 - (b * beta).sum(axis=1)
    i = int(np.argmin(sse))
    refine = cat.CATALOGUE[name].grid_refine
    if refine == "discrete":
        return float(values[i])
    if cat.CATALOGUE[name].fixed_gain and 0 < i < len(values) - 1:
        # a re-evaluation's error need not be quadratic over a grid step, and a few rows may carry most of what
        # identifies it (a lost-motion zone crossed in a few samples): that step's neighbourhood is scanned
        # again finely on every training row
        values = np.linspace(values[i - 1], values[i + 1], FINE_POINTS)
        d = np.stack([cat.columns_at(name, cols.data, float(v), train)[:, 0] for v in values])
        r = residual[train]
        n, r1 = float(len(train)), float(r.sum())
        sse = float(r @ r) - 2.0 * (d @ r) + (d * d).sum(axis=1) - (r1 - d.sum(axis=1)) ** 2 / n
        i = int(np.argmin(sse))
    if refine == "frequency":
        f = 1.0 / values
        order = np.argsort(f)
        fs, k = f[order], int(np.flatnonzero(order == i)[0])
        step = float(np.median(np.diff(fs))) if len(fs) > 2 else 0.0
        if 0 < k < len(fs) - 1 and max(fs[k] - fs[k - 1], fs[k + 1] - fs[k]) <= 1.5 * step:
            return 1.0 / _parabolic(fs, sse[order], k)
        # beside a band the grid leaves out (near the signal period): a parabola through a neighbour across the
        # band would put the period inside it; scan the admissible neighbourhood finely instead. Only when the
        # best admissible period is the one nearest the band is the data's period inside it (a beat with the
        # signal period): then it is taken there, where the identifiability check sees the two terms cancel
        f_fine = np.linspace(fs[k] - step, fs[k] + step, FINE_POINTS)
        f_fine = f_fine[(f_fine >= fs[0]) & (f_fine <= fs[-1])]  # the grid's span: ≥ 1.5 cycles, above p_min
        ok = cat.clear_of_signal_period(cols.data, 1.0 / f_fine)
        if ok.sum() < 3:
            return float(values[i])
        theta = cols.data.sim_angle_arcsec[scan_rows]
        fine_sse = np.full(len(f_fine), np.inf)
        fine_sse[ok] = [_periodic_sse(theta, w, r, 1.0 / float(f)) for f in f_fine[ok]]
        j = int(np.argmin(fine_sse))
        at_band = (j + 1 < len(ok) and not ok[j + 1]) or (j > 0 and not ok[j - 1])
        return 1.0 / _parabolic(fs, sse[order], k) if at_band else 1.0 / float(f_fine[j])
    return _parabolic(values, sse, i)


def _periodic_sse(theta: np.ndarray, w: np.ndarray, r: np.ndarray, period: float) -> float:
    """Weighted residual sum of squares of ``r`` after an offset and a sinusoid in ``theta`` of ``period``."""
    x = np.column_stack((np.ones(len(theta)), sincos(theta, period)))
    xw = x * w[:, None]
    beta = np.linalg.solve(xw.T @ x + 1e-9 * np.eye(3), xw.T @ r)
    e = r - x @ beta
    return float(e @ (w * e))


@dataclass
class FittedModel:
    """A model fitted on some rows: offset, nonlinear values and coefficients per effect."""

    names: list[str]
    nl: dict[str, float]
    beta: np.ndarray
    where: list[tuple[str, int, int]]

    @property
    def offset_arcsec(self) -> float:
        return float(self.beta[0])

    def parameters(self) -> dict[str, dict[str, float]]:
        return {name: cat.parameters(name, self.beta[a:b], self.nl.get(name)) for name, a, b in self.where}

    def predict(self, cols: Columns, rows: np.ndarray) -> np.ndarray:
        x, fixed, _ = _design(cols, self.names, self.nl, rows)
        return x @ self.beta + fixed


def fit_model(cols: Columns, y: np.ndarray, train: np.ndarray, names: list[str],
              nl: dict[str, float] | None = None, rescan: tuple[str, ...] | None = None) -> FittedModel:
    """Fit ``names`` on rows ``train``; nonlinear values of ``rescan`` (default: all without a value in ``nl``)
    are found by scanning the residual of the model without them, in order, then once more with all others."""
    nl = dict(nl or {})
    todo = [n for n in names if cat.CATALOGUE[n].nonlinear and (n in (rescan or ()) or n not in nl)]
    for name in todo:
        if name in (rescan or ()):
            nl.pop(name, None)
    sweeps = 2 if len(todo) > 1 else 1
    for _sweep in range(sweeps):
        for name in todo:
            others = [n for n in names if n != name and (not cat.CATALOGUE[n].nonlinear or n in nl)]
            x, fixed, _ = _design(cols, others, nl, train)
            beta = _solve(x, y[train] - fixed)
            resid = np.zeros(len(y))
            resid[train] = y[train] - fixed - x @ beta
            nl[name] = scan_nonlinear(cols, name, resid, train)
    x, fixed, where = _design(cols, names, nl, train)
    beta = _solve(x, y[train] - fixed)
    return FittedModel(list(names), nl, beta, where)


@dataclass
class CVScore:
    names: tuple[str, ...]
    fold_sse: np.ndarray
    fold_n: np.ndarray
    fold_models: list[FittedModel]

    @property
    def mse(self) -> float:
        return float(self.fold_sse.sum() / self.fold_n.sum())

    @property
    def rms(self) -> float:
        return math.sqrt(self.mse)

    @property
    def fold_mse(self) -> np.ndarray:
        return self.fold_sse / self.fold_n

    @property
    def se_mse(self) -> float:
        k = len(self.fold_n)
        return float(np.std(self.fold_mse, ddof=1) / math.sqrt(k)) if k > 1 else 0.0


def make_folds(rows: np.ndarray, groups: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Leave-one-group-out folds over ``rows`` (falls back to contiguous blocks for < 3 groups)."""
    if len(np.unique(groups[rows])) >= MIN_GROUPS:
        return leave_one_group_out(rows, groups[rows])
    return leave_one_group_out(rows, block_groups(len(rows)))


def cv_score(cols: Columns, y: np.ndarray, folds: list[tuple[np.ndarray, np.ndarray]], names: list[str],
             prev: CVScore | None = None) -> CVScore:
    """CV of ``names``; the nonlinear values of terms already in ``prev`` are kept per fold, new ones scanned."""
    sse, cnt, models = [], [], []
    for k, (train, test) in enumerate(folds):
        nl = dict(prev.fold_models[k].nl) if prev is not None else {}
        model = fit_model(cols, y, train, names, nl)
        e = y[test] - model.predict(cols, test)
        sse.append(float(e @ e))
        cnt.append(len(test))
        models.append(model)
    return CVScore(tuple(names), np.array(sse), np.array(cnt, dtype=float), models)


def _canonical_corr(a: np.ndarray, b: np.ndarray, base: np.ndarray) -> float:
    """Largest canonical correlation of the column spaces of ``a`` and ``b`` after projecting out ``base``."""
    qb = np.linalg.qr(base)[0]

    def resid_basis(m: np.ndarray) -> np.ndarray | None:
        r = m - qb @ (qb.T @ m)
        norms = np.linalg.norm(r, axis=0)
        if np.all(norms <= 1e-12 * (np.linalg.norm(m, axis=0) + 1e-300)):
            return None
        u, s, _ = np.linalg.svd(r, full_matrices=False)
        return u[:, s > 1e-10 * s.max()]

    qa, qc = resid_basis(a), resid_basis(b)
    if qa is None or qc is None:
        return 1.0
    return float(np.clip(np.linalg.svd(qa.T @ qc, compute_uv=False).max(), 0.0, 1.0))


def alias_correlation(cols: Columns, rows: np.ndarray, names: list[str], nl: dict[str, float],
                      a: tuple[str, float | None], b: tuple[str, float | None]) -> float:
    sub = rows[cols.in_scan[rows]] if np.count_nonzero(cols.in_scan[rows]) >= 8 else rows
    base, fixed, _ = _design(cols, names, nl, sub)
    if np.any(fixed):
        base = np.column_stack((base, fixed))
    return _canonical_corr(cols.rows_of(a[0], a[1], sub), cols.rows_of(b[0], b[1], sub), base)


def _median_nl(score: CVScore, name: str) -> float | None:
    vals = [m.nl[name] for m in score.fold_models if name in m.nl]
    return float(np.median(vals)) if vals else None


@dataclass
class Step:
    name: str
    score: CVScore
    aliases: list[str] = field(default_factory=list)


@dataclass
class Selection:
    base: CVScore
    steps: list[Step]
    chosen: int
    excluded: dict[str, str]

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.steps[: self.chosen]]

    def path(self) -> list[CVScore]:
        return [self.base] + [s.score for s in self.steps]


def select(cols: Columns, y: np.ndarray, rows: np.ndarray, candidates: list[str]) -> Selection:
    """Forward selection with the 1-SE rule over leave-one-group-out folds of ``rows``."""
    data = cols.data
    if cols.select_stride > 1:  # long, densely sampled runs: the choice of terms needs far fewer rows
        rows = rows[cols.in_select[rows]]
    folds = make_folds(rows, data.groups)
    base = cv_score(cols, y, folds, [])
    path = [base]
    steps: list[Step] = []
    names: list[str] = []
    remaining = list(candidates)
    excluded: dict[str, str] = {}
    while remaining and len(steps) < MAX_TERMS:
        scores = {c: cv_score(cols, y, folds, names + [c], path[-1]) for c in remaining}
        order = sorted(remaining, key=lambda c: scores[c].mse)
        best = None
        for c in order:
            if scores[c].rms > path[-1].rms * (1.0 - MIN_STEP_GAIN):
                break
            params = fit_model(cols, y, rows, names + [c], _prev_nl(path[-1], names)).parameters()[c]
            reason = cat.plausibility(c, params, data)
            if reason is not None:
                excluded[c] = reason
                remaining.remove(c)
                continue
            best = c
            break
        if best is None:
            break
        win = scores[best]
        aliases: list[str] = []
        nl_prev = _prev_nl(path[-1], names)
        if cat.CATALOGUE[best].grid_refine == "frequency" and cat.angle_follows_torque(data):
            aliases.append(cat.ONE_TO_ONE_ALIAS)  # any f(θ) is a g(T) here: the period is no evidence
        for c in order:
            if c == best or c in excluded or c in aliases:
                continue
            sc = scores[c]
            if sc.rms > path[-1].rms * (1.0 - MIN_GAIN):
                continue
            diff = sc.fold_mse - win.fold_mse
            se = float(np.std(diff, ddof=1) / math.sqrt(len(diff))) if len(diff) > 1 else 0.0
            if diff.mean() > max(se, 0.02 * win.mse):
                continue
            corr = alias_correlation(cols, rows, names, nl_prev, (best, _median_nl(win, best)),
                                     (c, _median_nl(sc, c)))
            if corr >= ALIAS_CORR:
                aliases.append(c)
        steps.append(Step(best, win, aliases))
        names.append(best)
        remaining.remove(best)
        path.append(win)
    mses = [p.mse for p in path]
    kmin = int(np.argmin(mses))
    threshold = path[kmin].mse + path[kmin].se_mse
    # the smallest model within one standard error of the best (the best itself qualifies: never empty)
    chosen = min(k for k in range(len(path)) if path[k].mse <= threshold or k == kmin)
    for j in range(chosen):
        if path[j + 1].rms > path[j].rms * (1.0 - MIN_GAIN):
            chosen = j
            break
    return Selection(base, steps, chosen, excluded)


def _prev_nl(score: CVScore, names: list[str]) -> dict[str, float]:
    out = {}
    for n in names:
        v = _median_nl(score, n)
        if v is not None:
            out[n] = v
    return out


@dataclass
class NestedResult:
    outer_sse: float
    outer_n: int
    inclusion: dict[str, float]
    fold_names: list[list[str]]
    residual: np.ndarray  # held-out residual of every row (outer folds)

    @property
    def rms(self) -> float:
        return math.sqrt(self.outer_sse / self.outer_n) if self.outer_n else float("nan")


def nested_cv(cols: Columns, y: np.ndarray, candidates: list[str]) -> NestedResult:
    """The whole selection inside every outer fold; the held-out error of the procedure, and how often
    each effect is selected across the outer folds (stability under leaving one group out)."""
    n = len(y)
    rows = np.arange(n)
    folds = make_folds(rows, cols.data.groups)
    sse, cnt = 0.0, 0
    counts: dict[str, int] = {}
    fold_names: list[list[str]] = []
    held = np.zeros(n)
    for train, test in folds:
        sel = select(cols, y, train, candidates)
        names = sel.names
        nl = _prev_nl(sel.steps[len(names) - 1].score, names) if names else {}
        model = fit_model(cols, y, train, names, nl, rescan=tuple(nl))
        e = y[test] - model.predict(cols, test)
        held[test] = e
        sse += float(e @ e)
        cnt += len(test)
        fold_names.append(names)
        for name in names:
            counts[name] = counts.get(name, 0) + 1
    inclusion = {c: counts.get(c, 0) / len(folds) for c in candidates}
    return NestedResult(sse, cnt, inclusion, fold_names, held)
