"""COBRA's URDF, shipped as package data ``cobra_model.urdf`` (see :mod:`cobra_model.shipped`)."""
