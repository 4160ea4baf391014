"""Scoring against the truth: estimation errors, ANEES and its interval (metrics), a flown run's
safety (safety) and the statistical tests that decide claims (stats). The per-estimator scoring
of a run is testbed.plugins.score with its hooks (testbed.plugins.hooks); see docs/architecture.md."""
