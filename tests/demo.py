"""The demo axis as a configuration file writes it: one builder for the tests and
benchmarks that start ``mebm serve`` (or parse a configuration) with the seed paper's Y
axis (``api.service.config.settings.demo_axis``: k_a 6.857 mm/rev, 16 mm lead, K = 10 1/s) and,
if asked, the demo's machining task (``DEMO_TASK``: the circle R200 F200, 45 µm)."""

from __future__ import annotations

from api.service.config.settings import DEMO_TASK, demo_axis


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, (tuple, list)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    return f"{v:g}" if isinstance(v, float) else str(v)


def demo_axis_toml(name: str = "y", *, travel_mm: tuple[float, float] = (0, 400), controller: str = "sim",
                   task: bool = True, **settings) -> str:
    """A ``[[machines.axes]]`` table of the demo axis named ``name``: its spec, ``travel_mm``,
    ``controller`` and the other axis ``settings`` given (``measure_feed_mm_min``,
    ``schedule_interval_s``, ``schedule_enabled``, ...), then the demo's circle task unless
    ``task`` is false."""
    spec = demo_axis().settings.spec
    lines = ["  [[machines.axes]]", f"  name = {_value(name)}",
             f"  transmission_mm_per_rev = {_value(spec.transmission_mm_per_rev)}",
             f"  screw_lead_mm = {_value(spec.screw_lead_mm)}",
             f"  position_gain_per_s = {_value(spec.position_gain_per_s)}",
             f"  travel_mm = {_value(list(travel_mm))}", f"  controller = {_value(controller)}"]
    lines += [f"  {k} = {_value(v)}" for k, v in settings.items()]
    if task:
        t = DEMO_TASK
        lines += ["    [[machines.axes.tasks]]", f"    name = {_value(t.name)}", f"    profile = {_value(t.profile)}",
                  f"    radius_mm = {_value(t.radius_mm)}", f"    feed_mm_min = {_value(t.feed_mm_min)}",
                  f"    tolerance_um = {_value(t.tolerance_um)}"]
    return "\n".join(lines) + "\n"


def demo_machine_toml(machine: str, *axes: str) -> str:
    """A ``[[machines]]`` table named ``machine`` holding the ``axes`` tables (each from
    :func:`demo_axis_toml`)."""
    return f'[[machines]]\nname = "{machine}"\n' + "".join(axes)
