"""thermonet: train, judge and export temperature-drift models for inertial sensors."""

__version__ = "0.1.0"
