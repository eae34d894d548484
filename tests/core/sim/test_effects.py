import pytest

from core.errors import InputError
from core.sim.effects import (
    CATEGORIES,
    BacklashProfile,
    Compliance,
    CyclicError,
    Effects,
    Friction,
    Thermal,
    parse_effect,
)


def test_parse_effect_gives_the_dataclass_with_typed_values():
    cat, fr = parse_effect("friction:coulomb_n=300,stribeck_velocity_mm_s=2,model=lugre")
    assert cat == "friction"
    assert fr == Friction(coulomb_n=300.0, stribeck_velocity_mm_s=2.0, model="lugre")
    cat, ce = parse_effect("cyclic_error:periods_mm=16/6.857,amplitudes_um=2;1,phases_deg=0/90")
    assert ce == CyclicError.of((16.0, 2.0, 0.0), (6.857, 1.0, 90.0))
    assert parse_effect("thermal") == ("thermal", Thermal())


@pytest.mark.parametrize(
    ("text", "named"),
    [
        ("frction:coulomb_n=1", ["'frction'", "friction", "sampling_skew"]),
        ("friction:coulomb=1", ["'coulomb'", "coulomb_n", "static_n"]),
        ("compliance:stiffness_n_per_um=abc", ["stiffness_n_per_um", "'abc'"]),
        ("thermal:lead_error_um_per_m", ["key=value"]),
    ],
)
def test_parse_effect_errors_name_the_value_and_the_valid_ones(text, named):
    with pytest.raises(InputError) as exc:
        parse_effect(text)
    for word in named:
        assert word in str(exc.value)


def test_every_category_parses_with_defaults():
    for cat in CATEGORIES:
        got_cat, obj = parse_effect(cat)
        assert got_cat == cat
        assert Effects().with_effect(cat, obj).active == (cat,)


@pytest.mark.parametrize(
    ("make", "named"),
    [
        (lambda: Friction(coulomb_n=300, static_n=200), "static_n (=200.0)"),
        (lambda: Friction(coulomb_n=-1), "coulomb_n (=-1)"),
        (lambda: Friction(model="dahl"), "'dahl'"),
        (lambda: Friction(coulomb_n=300, direction_asymmetry=1.0), "direction_asymmetry (=1.0)"),
        (lambda: Friction(coulomb_n=300, direction_asymmetry=float("nan")), "direction_asymmetry"),
        (lambda: Compliance(table_mass_kg=0), "table_mass_kg (=0)"),
        (lambda: BacklashProfile((0, 1), (10,)), "equal length"),
        (lambda: BacklashProfile((1, 0), (10, 10)), "strictly increasing"),
        (lambda: CyclicError(periods_mm=(0.0,), amplitudes_um=(1.0,)), "periods_mm"),
        (lambda: CyclicError(periods_mm=(0.05,), amplitudes_um=(5.0,)), "run backwards"),
        (lambda: Thermal(lead_growth_ppm_per_k=float("nan")), "lead_growth_ppm_per_k"),
        (lambda: Effects(friction=Compliance()), "effects.friction"),
    ],
)
def test_invalid_parameters_raise_input_error_naming_them(make, named):
    with pytest.raises(InputError, match=None) as exc:
        make()
    assert named in str(exc.value)


def test_static_friction_defaults_to_coulomb_and_guide_friction_to_two_percent_weight():
    assert Friction(coulomb_n=250).static_n == 250
    assert Compliance(table_mass_kg=2000).guide_friction_n == pytest.approx(0.02 * 9.81 * 2000)
    assert Compliance(table_mass_kg=100).guide_friction_n == 100.0
