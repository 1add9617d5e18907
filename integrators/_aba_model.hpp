// The Pinocchio model that integrators/_aba.cpp and tools/generate_aba.cpp build from a model's
// fields, as integrators/native.py hands them over (one row per joint after the universe).
#pragma once

#include <cstdint>
#include <string>

#include "pinocchio/multibody.hpp"

namespace cobra {

enum JointCode : int32_t { FREE_FLYER = 0, RX = 1, RY = 2, RZ = 3, REVOLUTE_UNALIGNED = 4 };

// Joint k (0-based) of n: its code, its parent's index, its placement in the parent's frame
// (row-major rotation then translation, 12 numbers), its body's inertia (mass, lever, then the
// symmetric 3x3 inertia as xx, xy, yy, xz, yz, zz: 10 numbers) and, for REVOLUTE_UNALIGNED, its
// axis (3). Returns false, the model unfinished, on a code it does not know.
inline bool build_model(int32_t n, const int32_t* code, const int32_t* parent, const double* placement,
                        const double* inertia, const double* axis, const double* armature, const double* gravity,
                        pinocchio::Model& model) {
  for (int32_t k = 0; k < n; ++k) {
    Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> R(placement + 12 * k);
    Eigen::Map<const Eigen::Vector3d> p(placement + 12 * k + 9);
    const Eigen::Matrix3d rotation = R;
    const Eigen::Vector3d translation = p;
    const pinocchio::SE3 M(rotation, translation);
    const std::string name = "joint_" + std::to_string(k + 1);
    pinocchio::JointIndex j;
    const pinocchio::JointIndex up = static_cast<pinocchio::JointIndex>(parent[k]);
    switch (code[k]) {
      case FREE_FLYER: j = model.addJoint(up, pinocchio::JointModelFreeFlyer(), M, name); break;
      case RX: j = model.addJoint(up, pinocchio::JointModelRX(), M, name); break;
      case RY: j = model.addJoint(up, pinocchio::JointModelRY(), M, name); break;
      case RZ: j = model.addJoint(up, pinocchio::JointModelRZ(), M, name); break;
      case REVOLUTE_UNALIGNED:
        j = model.addJoint(up, pinocchio::JointModelRevoluteUnaligned(axis[3 * k], axis[3 * k + 1], axis[3 * k + 2]),
                           M, name);
        break;
      default: return false;
    }
    const double* I = inertia + 10 * k;
    // assigned, not appended: appending sums inertias and would round differently
    model.inertias[j] = pinocchio::Inertia(I[0], Eigen::Vector3d(I[1], I[2], I[3]),
                                           pinocchio::Symmetric3(I[4], I[5], I[6], I[7], I[8], I[9]));
  }
  model.armature = Eigen::Map<const Eigen::VectorXd>(armature, model.nv);
  model.gravity.linear(Eigen::Vector3d(gravity[0], gravity[1], gravity[2]));
  return true;
}

}  // namespace cobra
