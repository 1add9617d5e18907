"""The discrepancy workflow: the effect library, residual signatures and the diagnosis."""
