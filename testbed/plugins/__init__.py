"""Estimators as plugins: the protocol (api), loading, feeding, scoring (the `[[estimators]]` table
itself is configuration: testbed.config.estimators).

Only the light protocol types are imported here (a plugin author imports them from
`testbed.plugins`); the machinery lives in its submodules.
"""
from testbed.plugins.api import Context, Estimate, EstimateBatch, Estimator, Measurement, MeasurementBatch
from testbed.config.estimators import EstimatorSpec

__all__ = ["Context", "Estimate", "EstimateBatch", "Estimator", "EstimatorSpec", "Measurement", "MeasurementBatch"]
