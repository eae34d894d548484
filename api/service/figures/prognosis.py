"""The ``prognosis`` figure: the seed paper's Fig. 10 extended with the
forecast of b̄ at the worst-case temperature and its confidence band.

A module of its own beside ``plots`` (whose helpers it uses): each render owns its
Figure and Agg canvas, as there.
"""

from __future__ import annotations

from datetime import datetime

from api.service.figures.plots import new_figure, png_bytes, thin_for_screen, with_temperature_axis


def prognosis(t: list[datetime], backlash_um: list[float], temperature_c: list[float | None], *,
              forecast_t: list[datetime] | None, forecast_um=None, band_low_um=None, band_high_um=None,
              worst_case_temperature_c: float, limit_um: float | None, limit_date: datetime | None,
              note: str, title: str) -> bytes:
    """Fig. 10 extended: b̄ and temperature over time, and the forecast of b̄ at the
    worst-case temperature with its confidence band, up to the backlash limit."""
    backlash_um, t, temperature_c = thin_for_screen(backlash_um, t, temperature_c)
    fig, (ax,) = new_figure(10, 5)
    ax.plot(t, backlash_um, "o", color="black", ms=3, label="mean backlash b̄ (measured)")
    if forecast_t:
        ax.plot(forecast_t, forecast_um, "-", color="#1f77b4", lw=1.6,
                label=f"forecast of b̄ at {worst_case_temperature_c:g} °C (worst case)")
        ax.fill_between(forecast_t, band_low_um, band_high_um, color="#1f77b4", alpha=0.2,
                        label="confidence band (95 %)")
    if limit_um is not None:
        ax.axhline(limit_um, color="#d62728", ls="-.", lw=1.4, label=f"backlash limit {limit_um:.1f} µm")
    if limit_date is not None:
        ax.axvline(limit_date, color="#d62728", ls=":", lw=1.2, label=f"limit reached {limit_date:%Y-%m-%d}")
    ax.set_xlabel("date (UTC)")
    ax.set_ylabel("mean backlash width b̄ (µm)")
    lines, labels = with_temperature_axis(ax, t, temperature_c, "s", ms=2, alpha=0.6)
    ax.legend(lines, labels, loc="upper left", fontsize=8, framealpha=0.9)
    ax.set_title(f"backlash prognosis — {title}\n{note}", fontsize=10)
    fig.autofmt_xdate()
    return png_bytes(fig)
