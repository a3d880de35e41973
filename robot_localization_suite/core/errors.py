"""Exception types of the package: each names the bad value it refuses."""

from __future__ import annotations

__all__ = [
    "LocalizationSuiteError",
    "MapError",
    "ScenarioError",
    "BagError",
    "ScanError",
    "CacheError",
    "ImageError",
    "SettingsError",
]


class LocalizationSuiteError(Exception):
    """Base class of every error this package raises on purpose."""


class MapError(LocalizationSuiteError):
    """A map file or message cannot be used (missing, corrupt, bad field)."""


class ScenarioError(LocalizationSuiteError):
    """A simulator scenario is inconsistent (bad field, pose inside an obstacle)."""


class BagError(LocalizationSuiteError):
    """A bag cannot be read or written."""


class ScanError(LocalizationSuiteError):
    """A laser scan cannot be turned into beams (bad geometry, no valid beam)."""


class CacheError(LocalizationSuiteError):
    """An on-disk precomputation cache is missing, stale or corrupt."""


class ImageError(LocalizationSuiteError):
    """A camera image cannot be used (wrong shape, non-finite values)."""


class SettingsError(LocalizationSuiteError, ValueError):
    """A setting or ROS parameter value is of the wrong type or out of its range."""
