"""What a person reads or watches: figures (plots), claims, tables and strict JSON (report), the
video of a run (render) and its overlays (render_overlay). Outputs import no workflow
(tests/test_architecture.py)."""
