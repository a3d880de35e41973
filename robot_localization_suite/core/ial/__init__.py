"""Guaranteed interval-analysis localization, Guyonneau et al. 2014 (``ial_localizer``); see docs/ial.md."""
