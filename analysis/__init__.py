"""Scaling-law analysis of handx-jax runs: reads result files only, never models or data.

Modules: ``schema`` (results table and run-folder contract), ``fits`` (log-linear and saturating
fits, bootstrap CIs, prediction intervals, extrapolation), ``tables`` (paper-style tables),
``plots`` (figures), ``paper`` (the HandX paper's Tables 2, 3, B and its Fig. 4 fit) and ``cli``
(``handx analyze``). Import the one you need; nothing is imported eagerly.
"""
