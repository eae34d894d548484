"""The gap diagnosis: :func:`diagnose` (dataset -> :class:`GapReport`).

1. Split the runs (given, or held out by condition), prepare round trips and contours
   (contours driven by their recorded command and scored on the data arc).
2. Fit the nominal model on the train runs: a constant backlash per axis (least squares
   on the table-given-motor play operator of the round trips, or on the train contours
   for an axis without round trips), K and k_a from the axis.
3. Its test gap: RMS over all test samples of measured minus predicted (table given
   motor for round trips, contour error for circles/lines), and where it lies.
4. Every registered family (:data:`core.gap.families.REGISTRY`): the nominal model extended
   with it, fitted on the train runs only, predicting the test runs. A round-trip axis
   takes the extension only if it passes a BIC test on its train fit; contours take the
   round-trip fit through the twin only if it does not worsen the train contours.
5. The second effect: every other candidate on top of the best single candidate that
   cuts the gap by min_reduction and of each single the held-out runs do not tell apart
   from it; where no single cuts it, the two best singles as a base with every other on
   top, and every other pair of candidates that took something (:func:`pair_jobs`).
6. The observations of the chain (:mod:`core.gap.evidence`): a table that breaks away at
   rest, a table that rattles against the nut.
7. The decision on that table (:func:`core.gap.select.select`): the best-scoring
   eligible hypothesis, evidence breaking ties only; the report's sentences come from
   the decision (:func:`core.gap.report.explain`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.signal import savgol_filter
from threadpoolctl import threadpool_limits

from core.dataset import Dataset
from core.gap import contour as ct
from core.gap import roundtrip as rt
from core.gap.data import Contour, GapError, RoundTrip, choose_split, prepare_runs, thin_train
from core.gap.evidence import observe
from core.gap.families import EFFECTS, REGISTRY
from core.gap.families.base import NOT_IDENTIFIABLE
from core.gap.report import Candidate, GapReport, explain, selection_dict
from core.gap.select import Rule, cuts, eligible_singles, ranked, select, ties_of
from core.gap.stages import NESTED_MIN_CUT, Stage, compose, stage_starts, train_residuals
from core.gap.where import breakaways, locate, rattles
from core.sim import AxisModel, Effects


@dataclass(frozen=True)
class GapSettings:
    """The decision's parameters (:class:`core.gap.select.Rule`) and what the report keeps.

    ``penalty_per_param``: the score is the held-out gap times (1 + this x parameters).
    ``min_reduction``: the fraction by which a hypothesis must cut a gap to be eligible, a
    second effect its base's gap, and the better of two hypotheses the worse one's for
    the held-out runs to tell them apart. ``noise_factor``: a gap within this multiple of
    the noise floor is noise. ``second_effect``: pairs are searched. ``min_first_reduction``:
    where nothing is eligible, the best single family is still named if it cuts the gap by
    this weaker fraction (off by default). ``keep_curves``: the report keeps the residual
    curves for plots."""

    penalty_per_param: float = 0.01
    min_reduction: float = 0.25
    noise_factor: float = 2.0
    second_effect: bool = True
    keep_curves: bool = True
    min_first_reduction: float | None = None

    def rule(self) -> Rule:
        return Rule(self.penalty_per_param, self.min_reduction, self.noise_factor, self.min_first_reduction)


WEAR_MIN_SPAN_DAYS = 1.0  # train round trips this many utility days apart or more show a wear rate
NOISE_DIFF_ORDER = 3  # the differences the white-noise level is read from (see noise_floor_um)


def white_level_um(resid: Sequence[np.ndarray], order: int = NOISE_DIFF_ORDER) -> float:
    """White-noise level of residuals: the MAD of their ``order``-th differences, pooled, /
    (0.6745 sqrt C(2k, k)) (for white noise of level s a k-th difference has the deviation
    s sqrt(C(2k, k)): sqrt 2 for first differences, sqrt 20 for third)."""
    k = int(order)
    parts = [np.diff(r, k) for r in resid if r.size > k + 1]
    if not parts:
        return 0.0
    d = np.concatenate(parts)
    return float(np.median(np.abs(d - np.median(d))) / 0.6745 / math.sqrt(math.comb(2 * k, k)))


def step_um(x_mm: np.ndarray) -> float:
    """The smallest step of a recorded position, µm: the encoder's resolution where the
    record is quantized (a 1 µm scale steps by 1 µm), next to nothing where it is not.
    The record must pass through rest somewhere, where it steps by one count (a round trip
    at its ends, an axis of a circle at its reversals); a record at speed throughout steps
    by several counts."""
    d = np.abs(np.diff(np.asarray(x_mm, dtype=float)))
    d = d[np.isfinite(d) & (d > 1e-9)]
    return float(d.min() * 1e3) if d.size else 0.0


# Samples at rest: an encoder whose speed (Savitzky-Golay over REST_SMOOTH_S) stays below
# REST_SPEED_FRACTION of its run's feed for at least REST_MIN_S; a level at rest needs
# REST_MIN_DIFFERENCES third differences inside such stretches.
REST_SPEED_FRACTION = 0.01
REST_SMOOTH_S = 0.02
REST_MIN_S = 0.1
REST_MIN_DIFFERENCES = 50


def rest_differences_um(t_s: np.ndarray, x_mm: np.ndarray, feed_mm_min: float) -> np.ndarray:
    """The third differences (µm) of one encoder's record inside its stretches at rest.

    Where nothing moves, what an encoder shows is its own noise: no motion of the chain
    reaches it, and an error of the reading that depends on the position (a scale's
    interpolation error, a period of 20-40 µm) is a constant there, while in motion it
    aliases into the differences of every sample. The decay of a stop (a loop settling, a
    chain ringing out) is smooth on the scale of three samples and passes."""
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(x_mm, dtype=float)
    if x.size < 8 or not feed_mm_min > 0:
        return np.zeros(0)
    dt = float(np.median(np.diff(t)))
    if not dt > 0:
        return np.zeros(0)
    n = max(5, 2 * int(round(REST_SMOOTH_S / dt / 2)) + 1)
    if n >= x.size:
        return np.zeros(0)
    v = savgol_filter(x, n, 2, deriv=1, delta=dt)
    still = np.abs(v) < REST_SPEED_FRACTION * feed_mm_min / 60.0
    edges = np.flatnonzero(np.diff(np.concatenate(([0], still.astype(np.int8), [0]))))
    need = max(NOISE_DIFF_ORDER + 2, int(math.ceil(REST_MIN_S / dt)))
    parts = [np.diff(x[a:b], NOISE_DIFF_ORDER) for a, b in zip(edges[::2], edges[1::2]) if b - a >= need]
    return np.concatenate(parts) * 1e3 if parts else np.zeros(0)


def rest_level_um(differences: Sequence[np.ndarray]) -> float | None:
    """White-noise level (µm) from third differences at rest (:func:`rest_differences_um`),
    pooled; None where fewer than REST_MIN_DIFFERENCES: no encoder stood still long enough."""
    d = np.concatenate([np.asarray(p, float) for p in differences]) if differences else np.zeros(0)
    if d.size < REST_MIN_DIFFERENCES:
        return None
    return float(np.median(np.abs(d - np.median(d))) / 0.6745 / math.sqrt(math.comb(2 * NOISE_DIFF_ORDER,
                                                                                   NOISE_DIFF_ORDER)))


def rest_levels_um(rts: Sequence[RoundTrip], cts: Sequence[Contour]) -> dict[tuple[str, str], float | None]:
    """Each encoder's white level at rest (µm), from every run of the dataset, train and
    test (the encoders are the same): ``("table", axis)`` from the round trips' table and
    the contours' records of the axis, ``("motor", axis)`` from the round trips' motor;
    None where it never stood still long enough."""
    diffs: dict[tuple[str, str], list[np.ndarray]] = {}
    for r in rts:
        diffs.setdefault(("table", r.axis), []).append(rest_differences_um(r.t_s, r.x_mm, r.feed_mm_min))
        diffs.setdefault(("motor", r.axis), []).append(rest_differences_um(r.t_s, r.u_mm, r.feed_mm_min))
    for c in cts:
        for a in c.axes:
            diffs.setdefault(("table", a), []).append(rest_differences_um(c.t_s, c.table_mm[a], c.feed_mm_min))
    return {k: rest_level_um(v) for k, v in diffs.items()}


def quantization_um(*records_mm: np.ndarray) -> float:
    """The RMS that the quantization of ``records_mm`` adds to a residual that takes each of
    them once (their differences: table given motor): sqrt(sum q^2 / 12) over their steps
    (:func:`step_um`)."""
    return math.sqrt(sum(step_um(x) ** 2 for x in records_mm) / 12.0)


def noise_floor_um(resid: Sequence[np.ndarray], groups: Sequence[str | None] | None = None,
                   quant_um: Sequence[float] | None = None,
                   rest_um: Sequence[float | None] | None = None) -> float:
    """The white-noise level of residuals (:func:`white_level_um`), as the RMS that a gap of
    white noise alone would have.

    ``groups``: one key per residual, or None. Residuals that share a key share their
    encoders (a round-trip axis: its table and motor encoders) and get one level, from
    their pooled differences; the others (key None, or no ``groups``) get the level of
    every residual's differences pooled. The floor is the root mean square of the levels
    weighted by the samples, the way the test gap pools them. Without groups it is the
    pooled level alone.

    Why: two axes' encoders differ in noise, and one median over both follows
    the quieter majority of samples while the RMS gap carries the noisier axis in full
    (x's round-trip noise 0.40 µm and y's 0.08 µm: one pooled level reads 0.16 µm, and a
    gap of 0.34 µm, white noise alone, stands at 2.15x it, past the 2x gate; with the
    axes apart the floor is 0.29 µm, 1.17x). Third differences, not first: a chain that
    stick-slips or rings through a whole stroke moves smoothly between samples, which
    first differences read as noise (a stick-slipping axis whose encoders carry 0.33 µm:
    7.17 µm from first differences, 0.36 µm from third; a two-mass chain's contours:
    13.8 µm from first, 0.60 µm from third), while on white noise all orders read the
    same (a sharp slip is a few samples: the median passes it). Contours keep the pooled
    level: sampled sparser, their differences still carry more of the contour's own
    motion.

    ``quant_um``: per residual, the RMS its encoders' quantization adds
    (:func:`quantization_um`), in quadrature beside the white level. A quantized record
    that moves slowly steps rarely, so its differences read almost no noise while the
    steps alone give resolution/sqrt(12): a 1 µm scale 0.29 µm RMS.

    ``rest_um``: per residual, the white level its encoders show at rest
    (:func:`rest_level_um`), or None: it replaces the level read from the residual's
    differences in motion, which also carry what moves faster than the samples (a scale's
    interpolation error: on the independent plant's seed 5807 a floor of 2.5-3.9 µm
    where the same plant's quiet cases read 0.3-0.5 µm). A residual whose encoders never
    stand still keeps the level in motion."""
    q_all = list(quant_um) if quant_um is not None else [0.0] * len(resid)
    r_all = list(rest_um) if rest_um is not None else [None] * len(resid)
    runs = [(r, None if groups is None else g, q, w)
            for r, g, q, w in zip(resid, groups or [None] * len(resid), q_all, r_all)
            if r.size > NOISE_DIFF_ORDER + 1]  # fmt: skip
    if not runs:
        return 0.0
    moving = [r for r, _, _, w in runs if w is None]
    pooled = white_level_um(moving) if moving else 0.0
    if groups is None and quant_um is None and rest_um is None:
        return pooled
    level = {g: white_level_um([r for r, k, _, w in runs if k == g and w is None])
             for g in {k for _, k, _, w in runs if k is not None and w is None}}  # fmt: skip
    n = np.array([r.size for r, *_ in runs], dtype=float)
    s = np.array([math.hypot(w if w is not None else pooled if g is None else level[g], q) for _, g, q, w in runs])
    return float(np.sqrt(np.sum(n * s * s) / np.sum(n)))


def _check(dataset: Dataset) -> None:
    if not dataset.runs:
        raise GapError("the dataset has no runs")
    for r in dataset.runs:
        for a in r.spec.axes:
            if a not in dataset.machine.axes:
                raise GapError(f"run {r.spec.file!r} uses axis {a!r}, which is not in machine.axes "
                               f"{sorted(dataset.machine.axes)}")  # fmt: skip
            if dataset.machine.axes[a].screw_lead_mm is None:
                raise GapError(f"axis {a!r} has no screw_lead_mm: the model's cyclic error and pitch "
                               "periods are the screw's, so the gap diagnosis needs it; add the ball "
                               f"screw's lead to machine.axes.{a} in dataset.json")  # fmt: skip
        for col in r.spec.columns_required():
            if col not in r.columns:
                raise GapError(f"run {r.spec.file!r} lacks column {col!r}")


def _bic_accepts(rss0: float, rss1: float, n: int, k: int) -> bool:
    return rss1 > 0 and n * math.log(max(rss0, 1e-12) / rss1) > k * math.log(max(n, 2))


def _rms_all(parts: Sequence[np.ndarray]) -> float:
    allr = np.concatenate(parts) if len(parts) else np.zeros(0)
    return rt.rms(allr)


@dataclass
class _AxisFit:
    """A round-trip axis' accepted composed model."""

    model: rt.RTModel
    fit: rt.FitResult
    stages: tuple
    effects: tuple[str, ...]
    gain: float = 0.0  # its BIC gain over the reference on the train runs (lower: better)
    train_ratio: float = 1.0  # its train RSS over the reference's, in the form's own metric


@dataclass
class Fitted:
    """One candidate (one or two effects) fitted on the train runs."""

    effects: tuple[str, ...]
    rt_fits: dict[str, _AxisFit] = field(default_factory=dict)
    # the fits on contours alone of a family fitted there only (Family.contour_fit): {family: {axis: FitResult}}
    ct_fits: dict[str, dict[str, rt.FitResult]] = field(default_factory=dict)
    params: dict = field(default_factory=dict)
    intervals: dict = field(default_factory=dict)
    n_params: int = 0
    notes: list[str] = field(default_factory=list)
    identifiable: bool = True
    rt_res: list = field(default_factory=list)
    ct_res: list = field(default_factory=list)
    gap_after_um: float = float("nan")
    # a family refitted on the contours (Family.contour_refit), per axis:
    # {family: {axis: (effects by name, backlash share µm, params)}}
    ct_refit: dict = field(default_factory=dict)
    # the decision's reading of it (core.gap.select.Hypothesis): its families whose
    # parameters the train runs do not pin down, the families its forms contain, every fit
    # ended at convergence, and its fit did not fail
    unidentified: frozenset = frozenset()
    contains: frozenset = frozenset()
    converged: bool = True
    fitted: bool = True

    def score(self, penalty: float) -> float:
        return self.gap_after_um * (1 + penalty * self.n_params)

    @property
    def identified(self) -> bool:
        return not self.unidentified


CONTOUR_SIGNAL_FACTOR = 1.5  # train contours whose residual RMS is within this of their noise show nothing


def _in_threads(calls: Sequence, workers: int) -> list:
    """The results of ``calls`` (callables without arguments), in order, run in up to
    ``workers`` threads (their time is in nogil numba kernels and numpy)."""
    def run(c):
        # a trial step may send a fit's parameters where the model overflows: the fit rejects
        # such steps (non-finite residuals are replaced, a diverged fit is a failed start), so
        # numpy's overflow warnings would only alarm the reader
        with np.errstate(over="ignore", invalid="ignore"):
            return c()

    if workers <= 1 or len(calls) <= 1:
        return [run(c) for c in calls]
    with ThreadPoolExecutor(min(workers, len(calls)), thread_name_prefix="mebm-gap-part") as ex:
        return list(ex.map(run, calls))


class _Diagnosis:
    def __init__(self, dataset: Dataset, settings: GapSettings, workers: int = 1):
        self.ds = dataset
        self.s = settings
        self.workers = workers  # threads for the independent parts of one candidate's fit
        self.axes = dataset.machine.axes
        self.memo = ct.SimMemo()
        # (family, axis) -> its round-trip fit on the nominal model and the notes on it
        self.alone: dict[tuple[str, str], tuple[_AxisFit | None, tuple[str, ...]]] = {}
        self.split = choose_split(dataset)
        rts, self.cts = prepare_runs(dataset, self.split)
        self.rts, self.thinned = thin_train(rts)
        self.rt_axes = sorted({r.axis for r in self.rts})
        self.train_rt = self._train_rt()
        for r in self.rts:
            if r.split == "test" and not self.train_rt[r.axis]:
                raise GapError(f"test round trip {r.file!r} of axis {r.axis!r} has no train round trip of that axis")
        self.train_ct = [c for c in self.cts if c.split == "train"]
        self.test_ct = [c for c in self.cts if c.split == "test"]
        self.test_rt = [r for r in self.rts if r.split == "test"]
        if not self.test_rt and not self.test_ct:
            raise GapError("no test run to diagnose on")
        if self.test_ct and not self.train_ct:
            missing = [a for c in self.test_ct for a in c.axes if a not in self.rt_axes]
            if missing:
                raise GapError(f"test contour(s) of axis {missing[0]!r} with neither train round trips nor train contours")

    def _train_rt(self) -> dict[str, list[RoundTrip]]:
        """Each axis' train round trips that the fits use (:func:`core.gap.data.thin_train`)."""
        return {a: [r for r in self.rts if r.axis == a and r.split == "train" and r.fitted] for a in self.rt_axes}

    def in_threads(self, calls: Sequence) -> list:
        """The results of ``calls`` in order, in up to the diagnosis' workers threads (:func:`_in_threads`)."""
        return _in_threads(calls, self.workers)

    # ---- nominal -------------------------------------------------------------------
    def fit_wear(self) -> None:
        """The wear of a stored history, part of the nominal model: where every round trip
        of an axis carries its utility day and the train runs span at least
        ``WEAR_MIN_SPAN_DAYS``, the axis' backlash grows linearly with the utility day (at
        a rate >= 0 fitted on the train runs with the backlash, referred to the newest
        train run's day), so that wear alone is not read as another effect. Each run then
        carries the backlash its day adds (``RoundTrip.wear_um``), in every model alike."""
        self.wear_um_per_day: dict[str, float] = {}
        self.wear_ref_day: dict[str, float] = {}
        for a in self.rt_axes:
            mine = [r for r in self.rts if r.axis == a]
            days = [r.utility_day for r in self.train_rt[a]]
            if any(r.utility_day is None for r in mine) or max(days) - min(days) < WEAR_MIN_SPAN_DAYS:
                continue
            ref = float(max(days))
            stage = Stage("wear", ("wear_um_per_day",), np.array([0.0]), np.array([0.0]), np.array([1e3]),
                          width=lambda th, run, u, hb, ref=ref: hb + 0.5e-3 * th[0] * (run.utility_day - ref))
            model = compose((stage,), rt.estimate_backlash_um(self.train_rt[a]), self.memo.misc)
            fr = rt.fit_model(model, self.train_rt[a], [np.array([model.x0[0], 1.0])], n_starts=2)
            rate = float(fr.theta[1])
            self.wear_um_per_day[a], self.wear_ref_day[a] = rate, ref
            self.rts = [replace(r, wear_um=rate * (r.utility_day - ref)) if r.axis == a else r for r in self.rts]
        if self.wear_um_per_day:
            self.train_rt = self._train_rt()
            self.test_rt = [r for r in self.rts if r.split == "test"]

    def fit_nominal(self) -> None:
        self.fit_wear()
        self.b_um: dict[str, float] = {}
        self.nom_fit: dict[str, rt.FitResult] = {}
        self.nom_model: dict[str, rt.RTModel] = {}
        for a in self.rt_axes:
            runs = self.train_rt[a]
            model = compose((), rt.estimate_backlash_um(runs), self.memo.misc)
            fr = rt.fit_model(model, runs)
            self.b_um[a] = float(fr.theta[0])
            self.nom_fit[a] = fr
            self.nom_model[a] = model
        ct_axes = sorted({a for c in self.cts for a in c.axes})
        for a in ct_axes:
            self.b_um.setdefault(a, 0.0)
        for a in ct_axes:
            if a not in self.rt_axes:
                self.b_um[a] = ct.fit_backlash_on_contours(self.memo, self.train_ct, self.axes, a, self.b_um)
        self.nominal_models = ct.models_for(self.axes, self.b_um)
        self.sim_nom = {c.file: self.memo.table(c, self.nominal_models) for c in self.cts}
        # test round trips are scored like contours, by envelope above 20 Hz (for every model
        # alike); the plain residuals give the noise floor and the where
        self.rt_nom_plain = [rt.residual_um(self.nom_model[r.axis].predict(self.nom_fit[r.axis].theta, r), r)
                             for r in self.test_rt]  # fmt: skip
        self.rt_nom = [rt.model_residual_um(self.nom_model[r.axis], self.nom_fit[r.axis].theta, r, envelope=True)
                       for r in self.test_rt]  # fmt: skip
        self.ct_nom = [ct.contour_residual_um(c, self.sim_nom[c.file]) for c in self.test_ct]
        self.ct_nom_plain = [ct.contour_plain_residual_um(c, self.sim_nom[c.file]) for c in self.test_ct]
        self.train_ct_rss_nom = self._ct_train_rss(self.sim_nom)
        self.fast_motion = {a: self._fast_motion(a) for a in ct_axes}
        self.ct_shows = {a: self.fast_motion[a] or self._contours_show_something(a) for a in ct_axes}

    def _fast_motion(self, a: str) -> bool:
        """Do the train contours of axis ``a`` carry fast motion (faster than the envelope
        window) beyond the nominal model's, above 3x the encoder noise? A chain that rings,
        stick-slips or hunts does; only then is a chain's dynamics refitted on contours."""
        if a not in self.rt_axes:
            return True  # no round trips to tell the encoder noise: the refit is tried
        # the encoder noise from the train round trips (smooth there but for it)
        d = np.concatenate([np.diff(r) for r in train_residuals(self.nom_model[a], self.nom_fit[a].theta,
                                                                  self.train_rt[a])])  # fmt: skip
        sigma = float(np.median(np.abs(d - np.median(d))) / 0.6745 / math.sqrt(2))
        fast = []
        for c in self.train_ct:
            if a not in c.axes:
                continue
            k = c.scored
            r = (c.table_mm[a][k] - self.sim_nom[c.file][a][k]) * 1e3
            n = max(3, int(round(ct.ENVELOPE_WINDOW_S * c.rate_hz)))
            if r.size < 2 * n:
                continue
            fast.append(r - uniform_filter1d(r, n, mode="nearest"))
        if not fast:
            return False
        return rt.rms(np.concatenate(fast)) > 3.0 * sigma

    def _contours_show_something(self, a: str) -> bool:
        """Does the nominal model leave anything on the train contours of axis ``a`` beyond
        their own white noise (the RMS of the tracking residual above 1.5 times the noise
        from its first differences, i.e. a systematic part above 1.1 times the noise)? If
        not, nothing there can pin friction's contour parameters down, and the refit is
        skipped (the round trips' friction is taken as it is). On the twin's datasets the
        ratio is 1.0 (none), 1.4-1.5 (thermal) and 2.5-10 (friction). Contours with fast
        motion (:meth:`_fast_motion`) always count as showing something: a stick-slipping
        or hunting table raises the noise estimated from first differences with it, so
        the ratio would hide the very motion the refit is for."""
        parts = [(c.table_mm[a][c.fit_idx] - self.sim_nom[c.file][a][c.fit_idx]) * 1e3 for c in self.train_ct
                 if a in c.axes and c.fit_idx.size > 2]  # fmt: skip
        if not parts:
            return False
        # first differences, the level this gate was set on (only the decision's floor reads third ones)
        return rt.rms(np.concatenate(parts)) > CONTOUR_SIGNAL_FACTOR * white_level_um(parts, order=1)

    def _ct_train_rss(self, sims: Mapping[str, dict]) -> float:
        return sum(float(np.sum(ct.tracking_envelope_residual_um(c, sims[c.file]) ** 2)) for c in self.train_ct)

    # ---- candidates ----------------------------------------------------------------
    def _fit_round_trips(self, new: str, a: str, bfit: _AxisFit | None, base_effects: tuple[str, ...],
                         retry: bool = False) -> tuple[_AxisFit | None, tuple[str, ...]]:
        """Family ``new`` fitted on axis ``a``'s train round trips, on top of ``bfit`` (the
        nominal model when None): the axis' fit if the BIC accepts it (None if not), and the
        notes on it. ``retry``: from the starts the first fit passed over (the next
        cheapest); a form without other starts is not fitted again."""
        notes: list[str] = []
        runs = self.train_rt[a]
        spec = self.axes[a]
        ref_model = bfit.model if bfit else self.nom_model[a]
        ref_fit = bfit.fit if bfit else self.nom_fit[a]
        fam = REGISTRY[new]
        resid = train_residuals(ref_model, ref_fit.theta, runs)
        made = fam.stage(runs, spec, resid)
        if made is None:
            return None, (f"{new} on axis {a}: {NOT_IDENTIFIABLE} ({fam.no_stage_reason})",)
        n = sum(r.fit_idx.size for r in runs)
        # each of the family's forms is fitted; the one with the best BIC is taken if it
        # passes the BIC test against the reference
        tried = []
        fitted_vals: dict[str, float] = {}  # the forms fitted so far, for derived starts
        for st in made if isinstance(made, tuple) else (made,):
            if st.derive_starts is not None:
                st = replace(st, starts=st.starts + tuple(st.derive_starts(fitted_vals)))
            if st.extends and not any(t[1].info.get("form") == st.extends for t in tried):
                continue  # a form that extends another is fitted from that one's values only
            stages = (bfit.stages if bfit else ()) + (st,)
            if sum(1 for x in stages if x.kernel) > 1:
                note = (f"axis {a}: {' and '.join(x.effect for x in stages)} both model the chain's dynamics; "
                        "not composed")  # fmt: skip
                if note not in notes:
                    notes.append(note)
                continue
            model = compose(stages, self.b_um[a], self.memo.misc)
            if bfit:
                model = replace(model, x0=np.concatenate([bfit.fit.theta, st.x0]))
                starts = [np.concatenate([bfit.fit.theta, s0]) for s0 in st.starts]
            else:
                starts = stage_starts(stages, np.array([self.b_um[a]]))
            # alone: the stage's own step and starts; on top of a base, whose parameters are
            # fitted again too, the default step (a 1 % step over all of them costs
            # twice the diagnosis' time)
            n_starts = 2 if st.starts and not bfit else 1
            if retry and len(starts) + 1 <= n_starts:
                continue
            fr = rt.fit_model(model, runs, starts, n_starts=n_starts, max_nfev=st.max_nfev,
                              diff_step=None if bfit else st.diff_step, skip=n_starts if retry else 0)
            fitted_vals.update(zip(model.names[-len(st.names):], fr.theta[-len(st.names):]))
            # the reference in the form's own metric (an envelope-scored chain against the
            # reference's residuals scored the same way, over the form's train windows)
            ref_rss = (rt.train_rss(ref_model, ref_fit.theta, runs, True, model.train_windows_s) if model.envelope
                       else ref_fit.rss)  # fmt: skip
            gain = n * math.log(max(fr.rss, 1e-12) / max(ref_rss, 1e-12)) + len(st.names) * math.log(max(n, 2))
            tried.append((gain, st, stages, model, fr, ref_rss))
        # a form that extends another of the family is kept over it only where it cuts its
        # train RSS by NESTED_MIN_CUT (Stage.extends)
        tried = [t for t in tried if not t[1].extends or all(
            t[4].rss <= (1.0 - NESTED_MIN_CUT) * b[4].rss for b in tried if b[1].info.get("form") == t[1].extends)]
        if not tried:
            return None, tuple(notes)
        gain, st, stages, model, fr, ref_rss = min(tried, key=lambda x: x[0])
        if not _bic_accepts(ref_rss, fr.rss, n, len(st.names)):
            notes.append(f"{new} on axis {a}: no train improvement (kept {'+'.join(base_effects) if bfit else 'nominal'})")
            return None, tuple(notes)
        if fr.capped:
            # pursued from where it stopped, once more with the same budget: a fit stopped at
            # its cap has not answered, and where it stopped moves with the numerics
            more = rt.fit_model(replace(model, x0=fr.theta), runs, (), n_starts=1, max_nfev=st.max_nfev,
                                diff_step=None if bfit else st.diff_step)  # fmt: skip
            if more.rss <= fr.rss:
                fr = more
                gain = n * math.log(max(fr.rss, 1e-12) / max(ref_rss, 1e-12)) + len(st.names) * math.log(max(n, 2))
        if fr.capped:
            notes.append(f"{new} on axis {a}: the round-trip fit stopped at its evaluation cap, not at convergence")
        return _AxisFit(model, fr, stages, tuple(s.effect for s in stages), gain,
                        fr.rss / max(ref_rss, 1e-12)), tuple(notes)

    def fit_single(self, effect: str) -> Fitted:
        """Family ``effect`` alone on the nominal model. A fit that fails (it makes the
        held-out gap worse than the nominal model's, or its parameters are not
        identifiable) is fitted again from other starts before it is ranked; of the two,
        the one the train runs prefer is kept (identifiable first, then the lower BIC on
        the train runs: the held-out runs never choose a fit). One that still makes the
        held-out gap worse is "not fitted": a fit that diverged, not a hypothesis that
        does not explain the gap."""
        f = self.fit_candidate((effect,))
        if not (self._worse(f) or (f.rt_fits and not f.identified)) or REGISTRY[effect].stage is None:
            return f
        if self.gap_before <= self.gate_um:
            # nothing is named within the noise gate (rule 1 of core.gap.select), whatever
            # a refit would give: the table keeps the first fit, and says so
            if self._worse(f):
                f.fitted = False
                f.notes.insert(0, "not fitted: the fit makes the held-out gap worse than the nominal model's "
                                  "(not fitted again: the gap before is within the noise)")  # fmt: skip
            return f
        again = self.fit_candidate((effect,), retry=True)
        if again.rt_fits and (again.identified, -self._train_gain(again)) > (f.identified, -self._train_gain(f)):
            why = "made the held-out gap worse" if self._worse(f) else "left its parameters unidentifiable"
            again.notes.insert(0, f"{effect}: fitted again from other starts (the first fit {why})")
            f = again
        if self._worse(f):
            f.fitted = False
            f.notes.insert(0, "not fitted: the fit makes the held-out gap worse than the nominal model's, "
                              "from other starts too")  # fmt: skip
        return f

    def fit_pair(self, effects: tuple[str, str], base: Fitted, singles: Mapping[str, Fitted]) -> Fitted:
        """The pair ``effects`` fitted on top of ``base`` (its first family alone). Two
        families that each stand in for the other alone (a backlash changing with
        temperature on strokes run at different temperatures reads as a profile along the
        travel) make the pair's cost multi-modal: from each base's values the joint fit
        ends in its own valley. A pair fit that fails (:meth:`fit_single`'s reading, or
        its second family cuts the base's train RSS by NESTED_MIN_CUT on a round-trip
        axis and nothing of its held-out gap: the train runs see it clearly, the
        held-out runs not at all) is fitted again from the other family's fit, and of
        the two the train runs choose (identifiable first, then the lower BIC on the
        train round trips; both hold the same forms); the held-out runs never choose a
        fit."""
        f = self.fit_candidate(effects, base)
        other = singles.get(effects[-1])
        seen = any(af is not base.rt_fits.get(a) and af.train_ratio <= 1.0 - NESTED_MIN_CUT
                   for a, af in f.rt_fits.items())  # fmt: skip
        idle = seen and not cuts(f.gap_after_um, base.gap_after_um, self.s.min_reduction)
        if other is None or not (idle or self._worse(f) or (f.rt_fits and not f.identified)):
            return f
        again = self.fit_candidate((effects[-1], effects[0]), other)
        if (again.identified, -self._train_bic(again)) > (f.identified, -self._train_bic(f)):
            why = ("made the held-out gap worse" if self._worse(f) else "left its parameters unidentifiable"
                   if not f.identified else f"cut nothing of {effects[0]}'s held-out gap")
            again.notes.insert(0, f"{'+'.join(effects)}: fitted again from {effects[-1]}'s fit (from "
                                  f"{effects[0]}'s it {why})")  # fmt: skip
            return again
        return f

    def _train_bic(self, f: Fitted) -> float:
        """BIC of ``f``'s round-trip fits on every round-trip axis (the nominal fit where it
        took none)."""
        total = 0.0
        for a in self.rt_axes:
            n = max(sum(r.fit_idx.size for r in self.train_rt[a]), 2)
            af = f.rt_fits.get(a)
            rss, k = (af.fit.rss, af.model.n_extra) if af else (self.nom_fit[a].rss, 0)
            total += n * math.log(max(rss, 1e-12)) + k * math.log(n)
        return total

    def _worse(self, f: Fitted) -> bool:
        """The nominal model cuts the candidate's held-out gap by ``min_reduction``: told
        apart as worse than no effect at all."""
        return cuts(self.gap_before, f.gap_after_um, self.s.min_reduction)

    @staticmethod
    def _train_gain(f: Fitted) -> float:
        return sum(af.gain for af in f.rt_fits.values())

    def fit_candidate(self, effects: tuple[str, ...], base: Fitted | None = None, retry: bool = False) -> Fitted:
        f = Fitted(effects)
        new = effects[-1]
        # round trips, axis by axis
        for a in self.rt_axes:
            bfit = base.rt_fits.get(a) if base else None
            if bfit:
                f.rt_fits[a] = bfit  # kept unless the new stage is accepted below
            if REGISTRY[new].stage is None:
                continue
            if bfit:
                fitted, notes = self._fit_round_trips(new, a, bfit, base.effects)
            else:
                # without a base fit on this axis the new family's fit depends on (family,
                # axis) alone: a pair whose base took nothing here (a contour-only family, a
                # stage the BIC refused) gets the single's fit, computed once
                key = (new, a, retry)
                if key not in self.alone:
                    self.alone[key] = self._fit_round_trips(new, a, None, (), retry)
                fitted, notes = self.alone[key]
            for note in notes:
                if note not in f.notes:
                    f.notes.append(note)
            if fitted is not None:
                f.rt_fits[a] = fitted
        # parameters of the round-trip fits
        for a, af in f.rt_fits.items():
            ivals = rt.intervals(af.fit, af.model.names, af.model.lower, af.model.upper)
            for name, v in zip(af.model.names, af.fit.theta):
                key = f"{a}.{name}"
                f.params[key] = float(v)
                f.intervals[key] = ivals[name]
            f.n_params += af.model.n_extra
            vals = dict(zip(af.model.names, af.fit.theta))
            for e in af.effects:
                for k, v in REGISTRY[e].derived(vals, float(af.fit.theta[0])).items():
                    f.params[f"{a}.{k}"] = float(v)
        # contours
        if self.cts:
            self._contours(f, base)
        if not self.rts and any(REGISTRY[e].stage is not None for e in effects):
            f.identifiable = False
            f.notes.append(f"{NOT_IDENTIFIABLE} without round trips")
        if REGISTRY[new].identifiable is not None:
            ok, note = REGISTRY[new].identifiable(self, f)
            if not ok:
                f.identifiable = False
            if note:
                f.notes.append(note)
        # test residuals
        f.rt_res = []
        for r in self.test_rt:
            af = f.rt_fits.get(r.axis)
            if af is None:
                f.rt_res.append(rt.model_residual_um(self.nom_model[r.axis], self.nom_fit[r.axis].theta, r, envelope=True))
            else:
                f.rt_res.append(bounded_residual(rt.model_residual_um(af.model, af.fit.theta, r, envelope=True),
                                         f"test round trip {r.file}", f.notes))
        f.gap_after_um = _rms_all(f.rt_res + f.ct_res)
        self._read(f)
        return f

    def _read(self, f: Fitted) -> None:
        """The decision's reading of a fitted candidate: its unidentified families (on no
        axis it took does the family have one identifiable parameter, or the family's own
        check fails), the families its forms contain, and whether every fit ended at
        convergence."""
        known: dict[str, bool] = {}  # family -> some axis pins one of its parameters down
        for a, af in f.rt_fits.items():
            for st in af.stages:
                if st.effect in f.effects and st.names:
                    pinned = any(f.intervals.get(f"{a}.{n}") is not None for n in st.names)
                    known[st.effect] = known.get(st.effect, False) or pinned
                if st.effect in f.effects:
                    f.contains |= frozenset(st.contains)
        for name, fits in f.ct_fits.items():
            cf = REGISTRY[name].contour_fit
            for a, fr in fits.items():
                if name in f.effects:
                    known[name] = known.get(name, False) or any(f.intervals.get(f"{a}.{n}") is not None
                                                                for n in fr.names or cf.names)  # fmt: skip
        lost = {e for e, ok in known.items() if not ok}
        if lost:
            f.notes.append(f"parameters not identifiable: {', '.join(sorted(lost))} (on every axis it took)")
        if not f.identifiable:
            lost.add(f.effects[-1])
        f.unidentified = frozenset(lost)
        f.converged = not any(af.fit.capped for af in f.rt_fits.values()) and not any(
            fr.capped for fits in f.ct_fits.values() for fr in fits.values())

    def _contours(self, f: Fitted, base: Fitted | None) -> None:
        pieces: dict[str, Effects] = {}
        bl = dict(self.b_um)
        for a, af in f.rt_fits.items():
            vals = dict(zip(af.model.names, af.fit.theta))
            fx = Effects()
            b = float(af.fit.theta[0])
            for st in af.stages:
                mine = {n: vals[n] for n in st.names}
                piece, b_share = REGISTRY[st.effect].sim_piece(mine, st.info, self.axes[a], b)
                for name, pc in piece if isinstance(piece, list) else [(st.effect, piece)]:
                    if pc is not None:
                        fx = fx.with_effect(name, pc)
                b -= b_share
            if not fx.is_nominal:
                pieces[a] = fx
                bl[a] = max(0.0, b)
        # the families' refits on contours, per axis whose round trips took the family
        # (independent: in threads); a pair on top of a base keeps the base's refit for the
        # axes it made one for
        for name, fam in REGISTRY.items():
            if fam.contour_refit is None:
                continue
            todo = [a for a, af in f.rt_fits.items() if name in af.effects and a in pieces and self.train_ct]
            base_refit = base.ct_refit.get(name, {}) if base is not None else {}
            reuse = {a: base_refit[a] for a in todo if a in base_refit}
            fresh = [a for a in todo if a not in reuse]
            calls = [lambda a=a, fam=fam: fam.contour_refit(self, a, f.rt_fits[a], pieces, bl) for a in fresh]
            done = dict(zip(fresh, self.in_threads(calls)))
            for a in todo:
                objs, b_share, params = reuse.get(a) or done[a]
                fx = pieces[a]
                for effect, pc in objs.items():
                    fx = fx.with_effect(effect, pc)
                pieces[a], bl[a] = fx, max(0.0, float(f.rt_fits[a].fit.theta[0]) - b_share)
                f.params.update({f"{a}.{k}": v for k, v in params.items()})
                f.ct_refit.setdefault(name, {})[a] = (objs, b_share, params)
        # the families fitted on contours alone: the new one fitted, a base's kept
        gains = {a: spec.position_gain_per_s for a, spec in self.axes.items()}
        for name, fam in REGISTRY.items():
            cf = fam.contour_fit
            if cf is None:
                continue
            src = base.ct_fits.get(name, {}) if base is not None and name in base.effects else {}
            if f.effects[-1] == name and self.train_ct:
                src = cf.fit(self, bl, pieces)
                f.notes += [f"{name} on axis {a}: the contour fit stopped at its evaluation cap, not at convergence"
                            for a, fr in src.items() if fr.capped]  # fmt: skip
            for a, fr in src.items():
                names = fr.names or cf.names  # a form with parameters of its own names them
                vals = dict(zip(names, fr.theta))
                pieces[a] = (pieces.get(a) or Effects()).with_effect(name, cf.piece(vals))
                if cf.gain is not None:
                    gains[a] = float(vals[cf.gain])
                f.ct_fits.setdefault(name, {})[a] = fr
                ivals = rt.intervals(fr, names, cf.lower if fr.lower is None else fr.lower,
                                     cf.upper if fr.upper is None else fr.upper)  # fmt: skip
                for n, v in vals.items():
                    f.params[f"{a}.{n}"] = float(v)
                    f.intervals[f"{a}.{n}"] = ivals[n]
                f.n_params += len(names)
        if not pieces:
            f.ct_res = list(self.ct_nom)
            return
        models = {a: AxisModel.from_axis_spec(spec, max(0.0, float(bl.get(a, 0.0))), effects=pieces.get(a))
                  for a, spec in self.axes.items()}  # fmt: skip
        models = {a: _with_gain(m, gains[a]) for a, m in models.items()}
        sims = {c.file: self.memo.table(c, models) for c in self.train_ct}
        if self.train_ct and self._ct_train_rss(sims) > self.train_ct_rss_nom:
            f.ct_res = list(self.ct_nom)
            f.notes.append("contours kept nominal (the fit worsens the train contours)")
            return
        for c in self.test_ct:
            sims[c.file] = self.memo.table(c, models)
        f.ct_res = [bounded_residual(ct.contour_residual_um(c, sims[c.file]), f"test contour {c.file}", f.notes)
                    for c in self.test_ct]  # fmt: skip


def _with_gain(m: AxisModel, gain: float) -> AxisModel:
    if gain == m.position_gain_per_s:
        return m
    return AxisModel(m.name, m.transmission_mm_per_rev, m.screw_lead_mm, float(gain), m.backlash_um, m.initial_side,
                     m.effects, m.encoders)  # fmt: skip


def bounded_residual(resid_um: np.ndarray, what: str, notes: list[str]) -> np.ndarray:
    """A test residual whose simulation diverged (non-finite, or beyond
    ``rt.NONFINITE_RESIDUAL``: seen on the independent plant, a friction chain fitted on
    round trips that grew to 1e68 µm on a test circle its train circles never showed)
    counts as ``NONFINITE_RESIDUAL`` per sample there, as in the fits, and the candidate's
    notes say so; the report then shows a candidate that cannot predict that run, not a
    number of 68 digits."""
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(resid_um) | (np.abs(resid_um) > rt.NONFINITE_RESIDUAL)
    if not bad.any():
        return resid_um
    notes.append(f"the model's simulation diverged on {what} ({int(bad.sum())} samples counted as "
                 f"{rt.NONFINITE_RESIDUAL:g} µm)")
    return np.where(bad, np.where(np.nan_to_num(resid_um) < 0, -1.0, 1.0) * rt.NONFINITE_RESIDUAL, resid_um)


TOOK_FRACTION = 0.98  # a candidate whose test gap is below this fraction of the gap before cut it


def _took_something(f: Fitted, gap_before: float) -> bool:
    """A candidate that took no axis on its own and cut no test gap is not tried in a pair."""
    return bool(f.rt_fits or f.ct_fits) or f.gap_after_um < TOOK_FRACTION * gap_before


def pair_jobs(singles: Sequence[Fitted], gap_before: float, gate_um: float, rule: Rule) -> list:
    """The pairs the search fits, as (effects, base). Where single families cut the gap by
    ``min_reduction``: every other family on top of the best of them and of each one the
    held-out runs do not tell apart from it (:func:`core.gap.select.ties_of`), each base
    above the noise gate. Where none does: the two best single families as a base with
    every other on top, then every other pair of families that took something, once each,
    from the better of the two (two effects that each alone extrapolate badly rank last by
    test gap); the bases are the best of the families that cut the held-out gap at all
    (below ``TOOK_FRACTION`` of it) before those that took something on the train runs
    only, whose part of the gap the held-out runs do not confirm. A family that took
    nothing (:func:`_took_something`) is in no pair, and a pair of the same two families
    is fitted once. A family "not fitted" alone (its fit makes the held-out gap worse)
    whose train fit was accepted goes on top of the bases all the same: fitted without
    the effect that is there beside it, it takes that effect's part and extrapolates it
    wrongly, which is what a pair is for."""
    took = [f for f in ranked(singles, rule.penalty_per_param) if f.fitted and _took_something(f, gap_before)]
    failed = [f for f in ranked(singles, rule.penalty_per_param) if not f.fitted and (f.rt_fits or f.ct_fits)]
    ok = eligible_singles([f for f in singles if f.fitted], gap_before, rule)
    if ok:
        bases = [b for b in [ok[0]] + ties_of(ok[0], ok, rule) if b.gap_after_um > gate_um]
    else:
        bases = sorted(took, key=lambda f: f.gap_after_um >= TOOK_FRACTION * gap_before)[:2]  # stable: by score within
    jobs = [((b.effects[0], t.effects[0]), b) for b in bases for t in took + failed if t.effects[0] != b.effects[0]]
    if not ok:
        jobs += [((a.effects[0], b.effects[0]), a) for i, a in enumerate(took) for b in took[i + 1:]]
    out, seen = [], set()
    for job in jobs:
        if frozenset(job[0]) not in seen:
            seen.add(frozenset(job[0]))
            out.append(job)
    return out


def _fitted_runs(train: Sequence[str], rts: Sequence[RoundTrip]) -> tuple[str, ...]:
    """The train runs the fits used: ``train`` but the round trips a thinning left out."""
    left = {r.file for r in rts if not r.fitted}
    return tuple(f for f in train if f not in left)


def _candidate(f: Fitted, s: GapSettings) -> Candidate:
    params: dict = {}
    for k, v in f.params.items():
        params[k] = NOT_IDENTIFIABLE if k in f.intervals and f.intervals[k] is None else v
    ivals = {k: (list(v) if v is not None else NOT_IDENTIFIABLE) for k, v in f.intervals.items()}
    axes_used = tuple(sorted(set(f.rt_fits) | {a for fits in f.ct_fits.values() for a in fits}))
    return Candidate("+".join(f.effects), f.gap_after_um, params, f.n_params, f.score(s.penalty_per_param),
                     f.identified, "; ".join(f.notes), axes_used, ivals, dict(f.params), f.fitted,
                     f.converged)  # fmt: skip


def _fit_all(d: _Diagnosis, jobs: list[tuple[tuple[str, ...], Fitted | None]], workers: int,
             singles: Mapping[str, Fitted]) -> list[Fitted]:
    """``d.fit_pair`` on each (effects, base), in order, in up to ``workers`` threads
    (:func:`_in_threads`). The answer is the same as one after the other: the diagnosis'
    memo holds pure results only, keyed by their inputs."""
    return _in_threads([lambda job=job: d.fit_pair(*job, singles) for job in jobs], workers)


def diagnose(dataset: Dataset, settings: GapSettings | None = None, *, workers: int | None = None) -> GapReport:
    """Diagnose the gap between the nominal model and the dataset's test runs.

    ``workers``: candidate fits run in that many threads (default: the machine's cores,
    at most 4); the report does not depend on it.

    Raises :class:`GapError` for a dataset it cannot work on (fewer than two runs, no test
    runs, an axis missing from ``machine.axes`` or without its screw lead, a test axis
    without train runs).
    """
    workers = min(os.cpu_count() or 1, 4) if workers is None else int(workers)
    s = settings or GapSettings()
    _check(dataset)
    # one BLAS thread: the fits' linear algebra is small (Jacobians of a few dozen columns),
    # and the parallel parts are the diagnosis' own threads. BLAS threads of their own only
    # spin between calls: two or three times the CPU, and slower
    with threadpool_limits(limits=1, user_api="blas"):
        return _diagnose(dataset, s, workers)


def _diagnose(dataset: Dataset, s: GapSettings, workers: int) -> GapReport:
    d = _Diagnosis(dataset, s, workers)
    d.fit_nominal()
    rt_nom, ct_nom = d.rt_nom, d.ct_nom
    gap_before = _rms_all(rt_nom + ct_nom)
    by_kind = {}
    if rt_nom:
        by_kind["round_trip"] = _rms_all(rt_nom)
    for kind in ("circle", "line"):
        parts = [r for c, r in zip(d.test_ct, ct_nom) if c.kind == kind]
        if parts:
            by_kind[kind] = _rms_all(parts)
    # white noise, from the plain sample-by-sample residuals: each round-trip axis its own
    # and each encoder's quantization, from the records' own smallest step
    quant = ([quantization_um(r.x_mm, r.u_mm) for r in d.test_rt]
             + [math.sqrt(sum(quantization_um(c.table_mm[a]) ** 2 for a in c.axes) / len(c.axes)) for c in d.test_ct])
    rest = rest_levels_um(d.rts, d.cts)
    rest_rt = [None if rest.get(("table", r.axis)) is None or rest.get(("motor", r.axis)) is None
               else math.hypot(rest[("table", r.axis)], rest[("motor", r.axis)]) for r in d.test_rt]
    rest_ct = [None if any(rest.get(("table", a)) is None for a in c.axes)
               else math.sqrt(sum(rest[("table", a)] ** 2 for a in c.axes) / len(c.axes)) for c in d.test_ct]
    noise = noise_floor_um(d.rt_nom_plain + d.ct_nom_plain, [r.axis for r in d.test_rt] + [None] * len(d.ct_nom_plain),
                           quant, rest_rt + rest_ct)  # fmt: skip
    at_rest = [w is not None for w in rest_rt + rest_ct]
    noise_from = "rest" if all(at_rest) else "motion" if not any(at_rest) else "rest and motion"

    rule = s.rule()
    gate = s.noise_factor * noise
    d.gap_before, d.gate_um = gap_before, gate
    fits = dict(zip(EFFECTS, _in_threads([lambda e=e: d.fit_single(e) for e in EFFECTS], workers)))
    singles = list(fits.values())
    pairs: list[Fitted] = []
    if s.second_effect and gap_before > gate:
        pairs = ranked(_fit_all(d, pair_jobs(singles, gap_before, gate, rule), workers, fits), s.penalty_per_param)
    found, broke = rattles(d.rts), breakaways(d.rts)
    observations = observe(broke, found, {e: st.shown_by for e, st in REGISTRY.items()})
    dec = select(singles, pairs, gap_before, noise, observations, rule)
    effect, chosen = dec.effect, dec.chosen
    single = fits.get(effect)
    decision, second_text = explain(dec, {e: f.gap_after_um for e, f in fits.items()}, s.second_effect,
                                    on_top=any(p.effects[0] == effect for p in pairs))  # fmt: skip
    effects_list = list(dec.effects)
    gap_after = gap_before if chosen is None else chosen.gap_after_um
    first = [single] if single is not None else []
    cands = [_candidate(f, s) for f in first + [f for f in ranked(singles, s.penalty_per_param) if f is not single]]
    none_c = Candidate("none", gap_before, {}, 0, gap_before, True, "the nominal model", ())
    ordered = ([none_c] + cands) if chosen is None else cands[:1] + [none_c] + cands[1:]

    all_runs = []
    for r in d.rts:
        all_runs.append((r, rt.residual_um(d.nom_model[r.axis].predict(d.nom_fit[r.axis].theta, r), r)))
    for c in d.cts:
        all_runs.append((c, ct.contour_plain_residual_um(c, d.sim_nom[c.file])))
    where = locate(
        d.test_rt, d.rt_nom_plain, d.test_ct, d.ct_nom_plain, d.b_um,
        {a: v.screw_lead_mm for a, v in d.axes.items()}, {a: v.transmission_mm_per_rev for a, v in d.axes.items()},
        all_runs,
    )  # fmt: skip
    where = replace(where, details={**where.details, "rattle": found, "breakaway": broke})
    quantity = {}
    if d.test_rt:
        quantity["round_trip"] = ("table position given the motor position (per-run offset fitted; sample by sample below 20 Hz, "
                                  "by envelope above)")
    if any(c.kind == "circle" for c in d.test_ct):
        quantity["circle"] = "radial contour error on the data arc (measured minus simulated)"
    if any(c.kind == "line" for c in d.test_ct):
        quantity["line"] = "perpendicular contour error on the data segment (measured minus simulated)"
    rebuilt = [c.file for c in d.cts if c.rebuilt]
    program_source = (
        "recorded command columns" if not rebuilt else
        f"rebuilt from the run fields (no command columns) for {', '.join(rebuilt)}: the lead-in is assumed"
    )  # fmt: skip
    curves = {}
    if s.keep_curves:
        after = (chosen.rt_res, chosen.ct_res) if chosen is not None else (rt_nom, ct_nom)
        curves = {
            "round_trip": [{"file": r.file, "axis": r.axis, "u_mm": r.u_mm[r.start :], "nominal_um": a, "corrected_um": b}
                           for r, a, b in zip(d.test_rt, rt_nom, after[0])],
            "contour": [{"file": c.file, "kind": c.kind, "angle_deg": c.angle_deg(), "nominal_um": a,
                         "corrected_um": b} for c, a, b in zip(d.test_ct, ct_nom, after[1])],
        }  # fmt: skip
    return GapReport(
        machine_id=dataset.machine.id,
        effect=effect,
        where=where,
        gap_before_um=gap_before,
        gap_after_um=gap_after,
        noise_floor_um=noise,
        noise_floor_from=noise_from,
        train=d.split.train,
        test=d.split.test,
        split_how=d.split.how + (f"; {d.thinned}" if d.thinned else ""),
        fitted=_fitted_runs(d.split.train, d.rts) if d.thinned else None,
        candidates=tuple(ordered),
        nominal_backlash_um=dict(d.b_um),
        nominal_wear={a: (r, d.wear_ref_day[a]) for a, r in d.wear_um_per_day.items()},
        quantity=quantity,
        gap_before_by_kind_um=by_kind,
        n_test_samples=int(sum(r.size for r in rt_nom + ct_nom)),
        decision=decision,
        thresholds={"penalty_per_param": s.penalty_per_param, "min_reduction": s.min_reduction,
                    "min_first_reduction": s.min_first_reduction, "noise_factor": s.noise_factor,
                    "second_effect": s.second_effect},  # fmt: skip
        curves=curves,
        effects=tuple(effects_list),
        second_effect=second_text,
        program_source=program_source,
        pairs=tuple(_candidate(f, s) for f in pairs),
        observations=tuple(o.seen for o in observations),
        close_alternatives=tuple(("+".join(f.effects), f.gap_after_um) for f in dec.ties),
        selection=selection_dict(dec),
    )
