"""The gap diagnosis: :func:`diagnose` (dataset -> :class:`GapReport`).

1. Split the runs (given, or held out by condition), prepare round trips and contours.
2. Fit the nominal model on the train runs: a constant backlash per axis (least squares
   on the table-given-motor play operator of the round trips, or on the train contours
   for an axis without round trips), K and k_a from the axis.
3. Its test gap: RMS over all test samples of measured minus predicted (table given
   motor for round trips, contour error for circles/lines), and where it lies.
4. Every effect category: the nominal model extended with it, fitted on the train runs
   only, predicting the test runs. An axis takes the extension only if it passes a BIC
   test on its train fit; contours take a round-trip fit through the simulator only if
   it does not worsen the train contours.
5. Rank by test gap times (1 + PENALTY_PER_PARAM * n_params); name the best unless it
   fails to cut the gap by MIN_REDUCTION or the gap is within NOISE_FACTOR of the noise.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from core.dataset import Dataset
from core.gap import contour as ct
from core.gap import roundtrip as rt
from core.gap.data import Contour, GapError, RoundTrip, choose_split, prepare_contour, prepare_round_trip
from core.gap.report import Candidate, GapReport
from core.gap.where import locate
from core.sim import Effects

EFFECTS = ("thermal", "backlash_profile", "cyclic_error", "friction", "compliance", "servo_dynamics", "sampling_skew")


@dataclass(frozen=True)
class GapSettings:
    """Decision thresholds (tuned on generated data, seeds 101-130; see docs/gap-diagnosis.md)."""

    penalty_per_param: float = 0.02
    min_reduction: float = 0.25  # best candidate must cut the test gap by at least this fraction
    noise_factor: float = 1.5  # ... and the gap before must exceed this multiple of the noise floor
    min_temperature_span_c: float = 1.0  # train temperatures needed for the thermal candidate
    keep_curves: bool = True


def noise_floor_um(resid: list[np.ndarray]) -> float:
    """White-noise level of residuals: MAD of first differences / (0.6745 sqrt 2), pooled."""
    d = np.concatenate([np.diff(r) for r in resid if r.size > 2])
    if d.size == 0:
        return 0.0
    return float(np.median(np.abs(d - np.median(d))) / 0.6745 / math.sqrt(2))


def _check(dataset: Dataset) -> None:
    if not dataset.runs:
        raise GapError("the dataset has no runs")
    for r in dataset.runs:
        for a in r.spec.axes:
            if a not in dataset.machine.axes:
                raise GapError(f"run {r.spec.file!r} uses axis {a!r}, which is not in machine.axes "
                               f"{sorted(dataset.machine.axes)}")  # fmt: skip
        for col in r.spec.columns_required():
            if col not in r.columns:
                raise GapError(f"run {r.spec.file!r} lacks column {col!r}")


def _bic_accepts(rss0: float, rss1: float, n: int, k: int) -> bool:
    return rss1 > 0 and n * math.log(max(rss0, 1e-12) / rss1) > k * math.log(max(n, 2))


class _Fitter:
    def __init__(self, dataset: Dataset, settings: GapSettings):
        self.ds = dataset
        self.s = settings
        self.axes = dataset.machine.axes
        split = choose_split(dataset)
        self.split = split
        self.rts: list[RoundTrip] = []
        self.cts: list[Contour] = []
        for run in dataset.runs:
            sp = "test" if run.spec.file in split.test else "train"
            if run.spec.kind == "round_trip":
                self.rts.append(prepare_round_trip(run, self.axes[run.spec.axes[0]], sp))
            else:
                self.cts.append(prepare_contour(run, sp))
        self.rt_axes = sorted({r.axis for r in self.rts})
        self.train_rt = {a: [r for r in self.rts if r.axis == a and r.split == "train"] for a in self.rt_axes}
        for r in self.rts:
            if r.split == "test" and not self.train_rt[r.axis]:
                raise GapError(f"test round trip {r.file!r} of axis {r.axis!r} has no train round trip of that axis")
        self.train_ct = [c for c in self.cts if c.split == "train"]
        self.extra_params: dict = {}
        self.test_ct = [c for c in self.cts if c.split == "test"]
        self.test_rt = [r for r in self.rts if r.split == "test"]
        if not self.test_rt and not self.test_ct:
            raise GapError("no test run to diagnose on")
        if self.test_ct and not self.train_ct:
            missing = [a for c in self.test_ct for a in c.axes if a not in self.rt_axes]
            if missing:
                raise GapError(f"test contour(s) of axis {missing[0]!r} with neither train round trips nor train contours")

    # ---- nominal -------------------------------------------------------------------
    def fit_nominal(self) -> None:
        self.b_um: dict[str, float] = {}
        self.rss_nom: dict[str, float] = {}
        self.n_fit: dict[str, int] = {}
        for a in self.rt_axes:
            runs = self.train_rt[a]
            b0 = rt.estimate_backlash_um(runs)
            theta, rss = rt.fit(rt.nominal_model(b0), runs)
            self.b_um[a] = float(theta[0])
            self.rss_nom[a] = rss
            self.n_fit[a] = sum(r.fit_idx.size for r in runs)
        for a in sorted({a for c in self.cts for a in c.axes}):
            if a not in self.b_um:
                self.b_um[a] = 0.0
        for a in sorted({a for c in self.cts for a in c.axes}):
            if a not in self.rt_axes:
                self.b_um[a] = ct.fit_backlash_on_contours(self.train_ct, self.axes, a, self.b_um)
        self.nominal_models = ct.models_for(self.axes, self.b_um)
        self.sim_nom = {c.file: ct.simulate_table(c, self.nominal_models) for c in self.cts}

    def rt_test_resid(self, predict_by_axis: Mapping[str, tuple]) -> list[np.ndarray]:
        out = []
        for r in self.test_rt:
            fn, theta = predict_by_axis[r.axis]
            out.append(rt.residual_um(fn(theta, r), r))
        return out

    def ct_resid(self, sims: Mapping[str, dict], which: list[Contour]) -> list[np.ndarray]:
        return [ct.contour_residual_um(c, sims[c.file]) for c in which]

    # ---- candidates ----------------------------------------------------------------
    def rt_candidate(self, effect: str) -> tuple[dict, dict, dict, str]:
        """Fit an effect per round-trip axis. Returns (predict_by_axis, params, used axes info, notes)."""
        pred = {a: (rt.predict_nominal, np.array([self.b_um[a]])) for a in self.rt_axes}
        params: dict = {}
        used: dict = {}
        notes = []
        for a in self.rt_axes:
            runs = self.train_rt[a]
            b0 = self.b_um[a]
            if effect == "thermal":
                temps = [r.temperature_c for r in runs]
                if max(temps) - min(temps) < self.s.min_temperature_span_c:
                    notes.append(f"axis {a}: not identifiable (train round trips at one temperature)")
                    continue
                model = rt.thermal_model(b0)
            elif effect == "backlash_profile":
                lo = min(float(np.min(r.u_mm)) for r in runs)
                hi = max(float(np.max(r.u_mm)) for r in runs)
                model = rt.profile_model(b0, lo, hi)
            elif effect == "cyclic_error":
                res = [rt.residual_um(rt.predict_nominal(np.array([b0]), r), r, r.fit_idx) for r in runs]
                spec = self.axes[a]
                periods, _ = rt.residual_periods_mm(runs, res, spec.screw_lead_mm, spec.transmission_mm_per_rev)
                model = rt.cyclic_model(b0, periods)
            elif effect == "friction":
                model = rt.friction_model(b0)
            elif effect == "compliance":
                model = rt.compliance_model(b0)
            elif effect == "sampling_skew":
                model = rt.skew_model(b0)
            else:
                raise AssertionError(effect)
            starts = []
            if effect == "compliance":
                starts = [np.array([b0, fn, 0.3, g, mu]) for fn in (15.0, 40.0, 100.0) for g in (2.0, 10.0)
                          for mu in (100.0, 1000.0)]
            elif effect == "sampling_skew":
                starts = [np.array([b0, tau]) for tau in (-6.0, -3.0, -1.0, 1.0, 3.0, 6.0)]
            elif effect == "friction":
                starts = [np.array([b0, ls, vs, cv]) for ls in (1.0, 4.0) for vs in (0.5, 3.0) for cv in (0.01, 0.05)]
            theta, rss = rt.fit(model, runs, starts, n_starts=2 if effect == "friction" else 1)
            if not _bic_accepts(self.rss_nom[a], rss, self.n_fit[a], model.n_extra):
                notes.append(f"axis {a}: no train improvement (kept nominal)")
                continue
            pred[a] = (model.predict, theta)
            used[a] = (model, theta)
            for k, v in zip(model.names, theta):
                params[f"{a}.{k}" if len(self.rt_axes) > 1 else k] = float(v)
            if effect == "compliance":
                pre = f"{a}." if len(self.rt_axes) > 1 else ""
                w2 = (2 * math.pi * theta[1]) ** 2
                params[pre + "m_over_k_ms2"] = float(1e6 / w2)
                params[pre + "backlash_um"] = float(max(0.0, theta[0] - 2e3 * theta[4] / w2))
            if effect == "friction":
                k = ct.ASSUMED_STIFFNESS_N_PER_UM
                params[f"{a}.static_excess_n_at_200n_per_um" if len(self.rt_axes) > 1
                       else "static_excess_n_at_200n_per_um"] = float(theta[1] * k)  # fmt: skip
        return pred, params, used, "; ".join(notes)

    def contour_with(self, effect: str, used: dict) -> dict | None:
        """Sim tables of all contours with the round-trip-fitted effect, or None if it has
        no contour counterpart or worsens the train contours."""
        if not self.cts or not used:
            return None
        effects: dict[str, Effects] = {}
        bl = dict(self.b_um)
        for a, (model, theta) in used.items():
            info = dict(model.info)
            if effect == "friction":
                # The Coulomb share of the lost motion hides in the backlash of round trips and
                # barely changes slow circles; assume static = 1.25 x Coulomb (guideways 1.1-1.5).
                info["coulomb_um"] = min(ct.STATIC_TO_COULOMB_EXCESS * theta[1], 0.45 * theta[0])
                self.extra_params[(effect, a)] = {"coulomb_lost_motion_um_assumed": info["coulomb_um"]}
            fx, b = ct.effect_for_sim(effect, dict(zip(model.names, theta)), info, self.axes[a])
            if fx.is_nominal:
                continue
            effects[a] = fx
            if b is not None:
                bl[a] = max(0.0, float(b))
        if not effects:
            return None
        models = ct.models_for(self.axes, bl, effects)
        sims = {c.file: ct.simulate_table(c, models) for c in self.train_ct}
        if self.train_ct:
            before = sum(float(np.sum(ct.tracking_residual_um(c, self.sim_nom[c.file]) ** 2)) for c in self.train_ct)
            after = sum(float(np.sum(ct.tracking_residual_um(c, sims[c.file]) ** 2)) for c in self.train_ct)
            if after > before:
                return None
        for c in self.test_ct:
            sims[c.file] = ct.simulate_table(c, models)
        return sims


def _rms_all(parts: list[np.ndarray]) -> float:
    allr = np.concatenate(parts) if parts else np.zeros(0)
    return rt.rms(allr)


def diagnose(dataset: Dataset, settings: GapSettings | None = None) -> GapReport:
    """Diagnose the gap between the nominal model and the dataset's test runs.

    Raises :class:`GapError` for a dataset it cannot work on (fewer than two runs, no test
    runs, an axis missing from ``machine.axes``, a test axis without train runs).
    """
    s = settings or GapSettings()
    _check(dataset)
    f = _Fitter(dataset, s)
    f.fit_nominal()
    nom_pred = {a: (rt.predict_nominal, np.array([f.b_um[a]])) for a in f.rt_axes}
    rt_nom = f.rt_test_resid(nom_pred)
    ct_nom = f.ct_resid(f.sim_nom, f.test_ct)
    gap_before = _rms_all(rt_nom + ct_nom)
    by_kind = {}
    if rt_nom:
        by_kind["round_trip"] = _rms_all(rt_nom)
    for kind in ("circle", "line"):
        parts = [r for c, r in zip(f.test_ct, ct_nom) if c.kind == kind]
        if parts:
            by_kind[kind] = _rms_all(parts)
    noise = noise_floor_um(rt_nom + ct_nom)

    cands: list[Candidate] = []
    curves_after: dict[str, tuple[list, list]] = {}
    for effect in EFFECTS:
        notes = ""
        params: dict = {}
        n_params = 0
        ident = True
        rt_res = rt_nom
        ct_res = ct_nom
        axes_used: tuple[str, ...] = ()
        if effect == "servo_dynamics":
            if f.train_ct:
                sp, _ = ct.fit_servo(f.train_ct, f.axes, f.b_um)
                fx = {a: Effects(servo_dynamics=ct.servo_effect(*v)) for a, v in sp.items()}
                models = ct.models_for(f.axes, f.b_um, fx)
                sims = {c.file: ct.simulate_table(c, models) for c in f.test_ct}
                ct_res = f.ct_resid(sims, f.test_ct)
                for a, (lag, dead) in sp.items():
                    params[f"{a}.velocity_lag_ms"] = lag
                    params[f"{a}.dead_time_ms"] = dead
                n_params = 2 * len(sp)
                axes_used = tuple(sp)
                if f.rts:
                    notes = "not identifiable from round trips (acts between command and motor): fitted on contours"
            else:
                ident = False
                notes = "not identifiable from round trips (acts between command and motor)"
        else:
            pred, params, used, notes = f.rt_candidate(effect)
            n_params = sum(m.n_extra for m, _ in used.values())
            axes_used = tuple(used)
            if f.test_rt:
                rt_res = f.rt_test_resid(pred)
            if used and f.test_ct:
                sims = f.contour_with(effect, used)
                for (e, a), extra in f.extra_params.items():
                    if e == effect:
                        for k, v in extra.items():
                            params[f"{a}.{k}" if len(f.rt_axes) > 1 else k] = v
                if sims is not None:
                    ct_res = f.ct_resid(sims, f.test_ct)
                elif effect != "sampling_skew":
                    notes = (notes + "; " if notes else "") + "contours kept nominal"
            if not f.rts:
                ident = False
                notes = "not identifiable without round trips"
            elif effect == "thermal" and not used and "not identifiable" in notes:
                ident = False
        gap_after = _rms_all(rt_res + ct_res)
        score = gap_after * (1 + s.penalty_per_param * n_params)
        cands.append(Candidate(effect, gap_after, params, n_params, score, ident, notes, axes_used))
        curves_after[effect] = (rt_res, ct_res)
    cands.sort(key=lambda c: c.score)
    best = cands[0]
    if gap_before <= s.noise_factor * noise:
        effect, decision = "none", (
            f"The test gap {gap_before:.2f} µm is within {s.noise_factor:g}x the noise floor ({noise:.2f} µm)."
        )
    elif best.gap_after_um > (1 - s.min_reduction) * gap_before:
        effect, decision = "none", (
            f"No candidate cuts the test gap by {s.min_reduction * 100:.0f} % or more "
            f"(best: {best.effect}, {best.gap_after_um:.2f} µm): the gap is not one of the modelled effects."
        )
    else:
        effect = best.effect
        decision = f"{best.effect} cuts the test gap by {(1 - best.gap_after_um / gap_before) * 100:.0f} %."
    gap_after = gap_before if effect == "none" else best.gap_after_um
    none_c = Candidate("none", gap_before, {}, 0, gap_before, True, "the nominal model", ())
    ordered = ([none_c] + cands) if effect == "none" else cands[:1] + [none_c] + cands[1:]

    all_runs = []
    for r in f.rts:
        fn, th = nom_pred[r.axis]
        all_runs.append((r, rt.residual_um(fn(th, r), r)))
    for c in f.cts:
        all_runs.append((c, ct.contour_residual_um(c, f.sim_nom[c.file])))
    where = locate(
        f.test_rt, rt_nom, f.test_ct, ct_nom, f.b_um,
        {a: v.screw_lead_mm for a, v in f.axes.items()}, {a: v.transmission_mm_per_rev for a, v in f.axes.items()},
        all_runs,
    )  # fmt: skip
    quantity = {}
    if f.test_rt:
        quantity["round_trip"] = "table position given the motor position (per-run offset fitted)"
    if any(c.kind == "circle" for c in f.test_ct):
        quantity["circle"] = "radial contour error (measured minus simulated)"
    if any(c.kind == "line" for c in f.test_ct):
        quantity["line"] = "perpendicular contour error (measured minus simulated)"
    curves = {}
    if s.keep_curves:
        after = curves_after.get(effect, (rt_nom, ct_nom))
        curves = {
            "round_trip": [{"file": r.file, "axis": r.axis, "u_mm": r.u_mm[r.start :], "nominal_um": a, "corrected_um": b}
                           for r, a, b in zip(f.test_rt, rt_nom, after[0])],
            "contour": [{"file": c.file, "kind": c.kind, "angle_deg": c.angle_deg(), "nominal_um": a,
                         "corrected_um": b} for c, a, b in zip(f.test_ct, ct_nom, after[1])],
        }  # fmt: skip
    return GapReport(
        machine_id=dataset.machine.id,
        effect=effect,
        where=where,
        gap_before_um=gap_before,
        gap_after_um=gap_after,
        noise_floor_um=noise,
        train=f.split.train,
        test=f.split.test,
        split_how=f.split.how,
        candidates=tuple(ordered),
        nominal_backlash_um=dict(f.b_um),
        quantity=quantity,
        gap_before_by_kind_um=by_kind,
        n_test_samples=int(sum(r.size for r in rt_nom + ct_nom)),
        decision=decision,
        thresholds={"penalty_per_param": s.penalty_per_param, "min_reduction": s.min_reduction,
                    "noise_factor": s.noise_factor},  # fmt: skip
        curves=curves,
    )
