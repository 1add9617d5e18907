"""The shipped reference dataset, package data ``sysid.reference`` (see :mod:`cobra_model.shipped`)."""
