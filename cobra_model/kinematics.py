"""Small rotation helpers (quaternion conventions of the run format and of Pinocchio)."""
from __future__ import annotations

import numpy as np
import pinocchio as pin


def quat_xyzw_to_matrix(quat_xyzw: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion stored (x, y, z, w) as Pinocchio does."""
    x, y, z, w = np.asarray(quat_xyzw, dtype=float) / np.linalg.norm(quat_xyzw)
    return pin.Quaternion(w, x, y, z).toRotationMatrix()


def yaw_of_quat_wxyz(quat_wxyz: np.ndarray) -> np.ndarray:
    """Heading [rad] (rotation of the body x axis about world z) of (..., 4) quaternions (w, x, y, z)."""
    w, x, y, z = np.moveaxis(np.asarray(quat_wxyz, dtype=float), -1, 0)
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
