"""The gap panel shows what the diagnosis observed beside its answer (a rattling table)
and the candidates its test runs do not tell apart from the answer, each as its own
paragraph, escaped, and nothing when there is nothing to say."""

from types import SimpleNamespace

from api.ui.routes import templates


def _render(observations, alternatives=None):
    report = {
        "effect": "none", "gap_before_um": 12.17, "gap_after_um": 12.17, "noise_floor_um": 0.25,
        "runs_used": ["rt_x_00.csv"], "computed_at": "2026-11-27T16:00:00+00:00", "candidates": [],
        "report": "Gap diagnosis of machine m1", "residuals": [],
    }  # fmt: skip
    if observations is not None:
        report["observations"] = observations
    if alternatives is not None:
        report["close_alternatives"] = alternatives
    return templates.get_template("_gap.html").render(
        gap="done", report=report, age_s=5.0, axis=SimpleNamespace(id=1), who=SimpleNamespace(csrf="t"))


def test_an_observation_is_shown_as_its_own_paragraph_and_escaped():
    html = _render(["The table rattles against the nut on 1 round trip(s): rt_x_00.csv <x> at 58 Hz."])
    assert '<p class="warn-text gap-observed">The table rattles against the nut' in html
    assert "&lt;x&gt;" in html and "<x>" not in html


def test_no_observation_no_paragraph():
    assert "gap-observed" not in _render([])
    assert "gap-observed" not in _render(None)  # a result kept from before observations existed: no key


def test_candidates_not_told_apart_are_named_with_their_gaps():
    html = _render([], [{"effect": "compliance", "gap_after_um": 12.004}, {"effect": "<thermal>", "gap_after_um": 13.5}])
    p = html[html.index('<p class="gap-alternatives">'):]
    p = " ".join(p[: p.index("</p>")].split())
    assert "do not tell none apart from compliance (12.00 µm), &lt;thermal&gt; (13.50 µm): each cuts" in p
    assert "gap-alternatives" not in _render([], []) and "gap-alternatives" not in _render([])


def test_the_decision_and_the_second_effect_are_said_beside_the_answer():
    report_html = templates.get_template("_gap.html").render(
        gap="done", report={"effect": "compliance", "gap_before_um": 42.97, "gap_after_um": 6.57, "noise_floor_um": 0.3,
                            "runs_used": ["a.csv"], "computed_at": "2026-11-27T16:00:00+00:00", "candidates": [],
                            "residuals": [], "decision": "compliance cuts the test gap by 85 %. The observations "
                            "(breakaway) point at <friction>", "second_effect": "No second effect found."},
        age_s=5.0, axis=SimpleNamespace(id=1), who=SimpleNamespace(csrf="t"))  # fmt: skip
    assert '<p class="gap-decision" id="gap-decision">compliance cuts the test gap by 85 %.' in report_html
    assert "&lt;friction&gt;" in report_html and '<p class="gap-second">No second effect found.</p>' in report_html
    assert "gap-decision" not in _render([])  # a result without a decision sentence: no paragraph
