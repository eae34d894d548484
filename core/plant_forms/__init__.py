"""A second, independent feed-drive plant that generates benchmark datasets.

Its drive model and effect forms (core.plant_forms.forms) differ from the ones the gap
diagnosis assumes, so a benchmark on its cases measures the diagnosis on data it does
not model exactly. ``make_forms_case(labels, rng, size)`` returns a :class:`FormsCase`:
the labels, every drawn parameter and a validated :class:`core.dataset.Dataset`.
"""

from core.plant_forms.case import LABELS, FormsCase, FormsSize, make_forms_case

__all__ = ["LABELS", "FormsCase", "FormsSize", "make_forms_case"]
