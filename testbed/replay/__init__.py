"""Recorded data (docs/replay.md): the format's reading and checks (spec, tables, recording),
`testbed replay` (run), `testbed export` (export), per-link statistics, and the factor-graph
estimator for multi-antenna robots (graph)."""
