"""The effect families as plugins: one module each, one interface, one registry."""

from __future__ import annotations

import importlib

import pytest

from core.gap import candidates
from core.gap.families import REGISTRY, Family
from core.sim import CATEGORIES


def test_the_registry_is_the_twins_effect_list():
    assert sorted(REGISTRY) == sorted(CATEGORIES)
    assert candidates.REGISTRY is REGISTRY


@pytest.mark.parametrize("name", sorted(CATEGORIES))
def test_each_family_is_its_own_module(name):
    module = importlib.import_module(f"core.gap.families.{name}")
    fam = module.FAMILY
    assert isinstance(fam, Family) and fam.name == name and REGISTRY[name] is fam
    assert fam.forms and "Not covered" in fam.forms
    # a family is fitted on round trips, on contours alone, or both
    assert fam.stage is not None or fam.contour_fit is not None


def test_the_dispatchers_reach_the_families():
    assert candidates.sim_piece("no such family", {}, {}, None, 0.0) == (None, 0.0)
    assert candidates.derived("thermal", {}, 10.0) == {}
    assert candidates.derived("compliance", {"natural_frequency_hz": 50.0, "guide_friction_mm_s2": 0.0}, 10.0)[
        "clearance_um"] == pytest.approx(10.0)  # fmt: skip
