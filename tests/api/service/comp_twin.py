"""A twin round trip with a known b(x) and lead error, and readers of the written tables
that do what the controllers do (for the compensation tests)."""

from __future__ import annotations

import numpy as np

from core.sim import AxisModel, BacklashProfile, CyclicError, Effects, Encoders, Thermal, round_trip, simulate
from core.sim.engine import Chain

TRAVEL_MM = (0.0, 300.0)
AXIS = AxisModel(
    backlash_um=0.0,
    effects=Effects(
        backlash_profile=BacklashProfile(positions_mm=(0.0, 150.0, 300.0), widths_um=(80.0, 140.0, 100.0)),
        thermal=Thermal(lead_error_um_per_m=40.0),  # a linear lead error (e_p = 12 µm over 300 mm)
        cyclic_error=CyclicError.of((100.0, 3.0, 30.0)),  # and a long-period one a 5 mm table can follow
    ),
    encoders=Encoders(table_resolution_um=0.05, table_noise_um=0.1),
)


def simulate_round_trip():
    """The twin's round trip over the travel (plus 5 mm for the reversals), 250 Hz."""
    return simulate({"y": AXIS}, round_trip(TRAVEL_MM[0] - 5.0, TRAVEL_MM[1] + 5.0, 1500.0), temperature_c=20.0,
                    rate_hz=250.0, rng=np.random.default_rng(1))


def truth_um(nominal_mm, reference_mm: float = 0.0):
    """(e+, e-) = actual - nominal of the twin, µm, with the midline zero at ``reference_mm``:
    the nut runs at nut(u), the table a half backlash behind it (Eq. 5)."""
    ch = Chain.of(AXIS, 20.0)

    def raw(u):
        u = np.asarray(u, dtype=float)
        nut = ch.nut_mm(u)
        half = ch.half_width_at(nut)
        return (nut - u - half) * 1e3, (nut - u + half) * 1e3

    f0, r0 = raw([reference_mm])
    shift = -0.5 * (f0[0] + r0[0])
    f, r = raw(nominal_mm)
    return f + shift, r + shift


def read_linuxcnc(text: str, comp_type: int):
    """Nominal (mm) and actual - nominal (µm) per direction, read as LinuxCNC's
    usrmotLoadComp reads: triplets until the first line that is not one; type 0 is
    turned into trims as nominal - value, type 1 taken as the trims; the motion module
    adds the trim to the command, so actual - nominal = -trim."""
    rows = []
    for line in text.splitlines():
        parts = line.split()
        try:
            nom, a, b = (float(p) for p in parts)
        except ValueError:
            break
        rows.append((nom, a, b))
    arr = np.array(rows)
    nom = arr[:, 0]
    trim_f, trim_r = (nom - arr[:, 1], nom - arr[:, 2]) if comp_type == 0 else (arr[:, 1], arr[:, 2])
    return nom, -trim_f * 1e3, -trim_r * 1e3


def read_beckhoff(text: str):
    """Setpoints (mm) and pos/neg (µm, actual - setpoint) of an ISG kw.ssfk list; checks
    the equidistant header against the setpoints."""
    kv = {}
    for line in text.splitlines():
        if line.startswith("#") or not line.strip():
            continue
        key, value = line.split(None, 1)
        kv[key] = value.strip()
    n = int(kv["kw.ssfk.kw_nr_max"])
    assert kv["kw.ssfk.bilateral"] == "1" and kv["kw.ssfk.unit"] == "1"
    setpoint = np.array([int(kv[f"kw.ssfk.table[{i}].setpoint"]) for i in range(n)])
    start, interval = int(kv["kw.ssfk.kw_startpos"]), int(kv["kw.ssfk.interval"])
    assert np.array_equal(setpoint, start + interval * np.arange(n))
    pos = np.array([int(kv[f"kw.ssfk.table[{i}].pos"]) for i in range(n)])
    neg = np.array([int(kv[f"kw.ssfk.table[{i}].neg"]) for i in range(n)])
    return setpoint * 1e-4, pos * 0.1, neg * 0.1
