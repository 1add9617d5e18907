"""Identification: the objective, least squares, PPO (env, executor), intervals, the data check."""
