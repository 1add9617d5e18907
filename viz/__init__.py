"""Browser replays of COBRA runs (meshcat).

:mod:`viz.replay` is the entry point: :func:`viz.replay.write_replay_html` writes one
self-contained HTML file in which a measured run plays beside simulated ones, and
:func:`viz.replay.serve_replay` shows the same scene live from a meshcat server bound to
127.0.0.1. Importing :mod:`viz` or :mod:`viz.replay` does not import meshcat; the functions
that need it raise an :class:`ImportError` that says how to install it.
"""
