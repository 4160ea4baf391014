"""Estimators as plugins: the protocol (api), scenario selection (spec), loading, feeding, scoring.

Only the light protocol types are imported here (a plugin author imports them from
`testbed.plugins`); the machinery lives in its submodules.
"""
from testbed.plugins.api import Context, Estimate, EstimateBatch, Estimator, Measurement, MeasurementBatch
from testbed.plugins.spec import EstimatorSpec

__all__ = ["Context", "Estimate", "EstimateBatch", "Estimator", "EstimatorSpec", "Measurement", "MeasurementBatch"]
