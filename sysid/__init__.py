"""Identification: gap metrics, the objective, least squares, PPO and the discrepancy workflow."""
