"""Example configurations, shipped as package data ``hardware.examples`` (see :mod:`cobra_model.shipped`)."""
