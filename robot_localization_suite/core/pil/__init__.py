"""Pseudo Image Localization, Lambert et al. 2020 (``pil_localizer``); see docs/pil.md."""
