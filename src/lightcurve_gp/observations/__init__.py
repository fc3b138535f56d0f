"""Observations: the samples of one object's brightness that every estimator takes (:class:`Observations`)."""

from lightcurve_gp.observations.observations import CurveInfo, Observations, ObservationsError

__all__ = ["CurveInfo", "Observations", "ObservationsError"]
