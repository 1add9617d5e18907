"""Identification of COBRA's model from recorded runs, in four subpackages by role.

- :mod:`sysid.gap`: how far a simulation is from a measured run (metrics, plots, reports).
- :mod:`sysid.identification`: the objective, least squares, PPO, their executor, intervals and
  the data check before a fit.
- :mod:`sysid.discrepancy`: the effect library, residual signatures and the diagnosis.
- :mod:`sysid.generators`: data made for testing the above (the reference dataset, MuJoCo runs).
"""
