"""The one place :mod:`viz` imports meshcat: a missing install becomes a clear ImportError.

Modules that draw with meshcat import ``meshcat``/``mg`` from here; :mod:`viz.replay` imports
those modules only inside the functions that need them, so ``import viz.replay`` works without
meshcat.
"""
from __future__ import annotations

try:
    import meshcat
    import meshcat.animation as animation
    import meshcat.geometry as mg
except ImportError as exc:  # pragma: no cover - exercised by hiding meshcat in a test
    raise ImportError(
        f"the COBRA replay viewer needs meshcat, which could not be imported ({exc}); "
        "install it with `pip install meshcat`"
    ) from exc

__all__ = ["animation", "meshcat", "mg"]
