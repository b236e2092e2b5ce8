"""Exceptions of exo_has_sim; every error raised on purpose derives from :class:`SimError`."""

from __future__ import annotations

from exo_has_common.errors import ExoHasError


class SimError(ExoHasError):
    """Base of the errors raised by exo_has_sim."""


class ParameterError(SimError, ValueError):
    """A parameter set that is missing values, malformed, or physically implausible."""


class KinematicsError(SimError, ValueError):
    """A joint angle or cylinder length outside what the linkage can reach."""


class SimulationError(SimError, RuntimeError):
    """A simulation that cannot be run or diverged."""


class DiagnosisError(SimError):
    """A model-error diagnosis that cannot be made (base of the diagnosis errors)."""


class MeasurementError(DiagnosisError, ValueError):
    """Measured data that are missing, malformed, or in the wrong units (names the problem)."""


class FitError(DiagnosisError, RuntimeError):
    """A fit that cannot be made or did not converge to a usable result."""
