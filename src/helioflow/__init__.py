"""helioflow: learn heliostat focal spots from calibration images and compose field flux maps."""

__version__ = "0.1.0"
