// Pinocchio's articulated-body algorithm (and, for the soft-constraint contact, the inverse mass
// matrix from the same pass) behind a C interface, so that the simulator's compiled
// (numba) loops call them per step without a trip through Python.
//
// The model is rebuilt here from the Python model's own fields (joint types, parents,
// placements, inertias, armature, gravity), copied value for value, and ABA is the explicit
// instantiation that libpinocchio_default ships (PINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION, the
// Eigen::Ref argument types of the extern template): the same machine code that `pin.aba` runs,
// so the accelerations are bit for bit those of `pin.aba` on the Python model. The inverse mass
// matrix takes the Python binding's path too; tests/test_native_aba.py checks both bit for bit.
// Only what the simulator's kinematic chains hold is accepted: one free-flyer root and revolute
// joints (aligned with x, y, z or not).
#include <Python.h>

#include <cstdint>
#include <vector>

#include "pinocchio/algorithm/aba.hpp"
#include "pinocchio/multibody.hpp"

namespace {

using Model = pinocchio::Model;
using Data = pinocchio::Data;
using VectorXd = Eigen::VectorXd;
using ConstRef = Eigen::Ref<const VectorXd>;

// Joint type codes, as integrators/native.py packs them.
enum JointCode : int32_t { FREE_FLYER = 0, RX = 1, RY = 2, RZ = 3, REVOLUTE_UNALIGNED = 4 };

}  // namespace

extern "C" {

// A Pinocchio model of `n` joints (the universe excluded), joint k with
//   code[k] (JointCode), parent[k] (0 = universe), placement[12 k ...] = rotation (row-major 3x3)
//   then translation [m] in the parent joint's frame, inertia[10 k ...] = mass [kg], centre of
//   mass (3) [m], rotational inertia about it in Pinocchio's Symmetric3 order (xx, xy, yy, xz,
//   yz, zz) [kg m^2], axis[3 k ...] = the unaligned revolute axis (unused otherwise);
// armature (nv,) [kg m^2] and gravity (3,) [m/s^2]. Returns 0 for an unknown joint code.
intptr_t cobra_model_new(int32_t n, const int32_t* code, const int32_t* parent, const double* placement,
                         const double* inertia, const double* axis, const double* armature, const double* gravity) {
  Model* model = new Model();
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
      case FREE_FLYER: j = model->addJoint(up, pinocchio::JointModelFreeFlyer(), M, name); break;
      case RX: j = model->addJoint(up, pinocchio::JointModelRX(), M, name); break;
      case RY: j = model->addJoint(up, pinocchio::JointModelRY(), M, name); break;
      case RZ: j = model->addJoint(up, pinocchio::JointModelRZ(), M, name); break;
      case REVOLUTE_UNALIGNED:
        j = model->addJoint(up, pinocchio::JointModelRevoluteUnaligned(axis[3 * k], axis[3 * k + 1], axis[3 * k + 2]),
                            M, name);
        break;
      default: delete model; return 0;
    }
    const double* I = inertia + 10 * k;
    // assigned, not appended: appending sums inertias and would round differently
    model->inertias[j] = pinocchio::Inertia(I[0], Eigen::Vector3d(I[1], I[2], I[3]),
                                            pinocchio::Symmetric3(I[4], I[5], I[6], I[7], I[8], I[9]));
  }
  model->armature = Eigen::Map<const VectorXd>(armature, model->nv);
  model->gravity.linear(Eigen::Vector3d(gravity[0], gravity[1], gravity[2]));
  return reinterpret_cast<intptr_t>(model);
}

void cobra_model_free(intptr_t model) { delete reinterpret_cast<Model*>(model); }

// Pinocchio's workspace for `model`; one per environment that steps in parallel.
intptr_t cobra_data_new(intptr_t model) { return reinterpret_cast<intptr_t>(new Data(*reinterpret_cast<Model*>(model))); }

void cobra_data_free(intptr_t data) { delete reinterpret_cast<Data*>(data); }

// The acceleration a (nv,) = ABA(q (nq,), v (nv,), tau (nv,)) in Pinocchio's WORLD convention,
// as `pin.aba(model, data, q, v, tau, pin.Convention.WORLD)`. The joint accelerations are the
// LOCAL convention's to roundoff; WORLD accumulates the articulated inertias in the world frame,
// so the backward pass does not carry each one through its joint's placement (a 6x6 congruence
// per joint), and costs 12-14 % less on COBRA (2.29-2.35 against 2.66 us per call). Returns 0.
int32_t cobra_aba(intptr_t model, intptr_t data, const double* q, const double* v, const double* tau, double* a) {
  const Model& m = *reinterpret_cast<Model*>(model);
  Data& d = *reinterpret_cast<Data*>(data);
  const ConstRef qr = Eigen::Map<const VectorXd>(q, m.nq);
  const ConstRef vr = Eigen::Map<const VectorXd>(v, m.nv);
  const ConstRef tr = Eigen::Map<const VectorXd>(tau, m.nv);
  Eigen::Map<VectorXd>(a, m.nv) = pinocchio::aba(m, d, qr, vr, tr, pinocchio::Convention::WORLD);
  return 0;
}

// For the soft-constraint contact: the acceleration without contact a (nv,) = ABA(q, v, tau)
// and D(q)^-1 into minv (nv x nv, row-major; its upper triangle, as Pinocchio fills it) from one
// articulated-body pass, as `pin.aba(model, data, q, v, tau, pin.Convention.WORLD)` then
// `pin.computeMinverse(model, data)`, which reuses that pass's articulated inertias (the soft law
// took computeMinverse(q) and nonLinearEffects(q, v) before: two passes). Returns 0.
int32_t cobra_aba_minverse(intptr_t model, intptr_t data, const double* q, const double* v, const double* tau,
                           double* a, double* minv) {
  const Model& m = *reinterpret_cast<Model*>(model);
  Data& d = *reinterpret_cast<Data*>(data);
  const ConstRef qr = Eigen::Map<const VectorXd>(q, m.nq);
  const ConstRef vr = Eigen::Map<const VectorXd>(v, m.nv);
  const ConstRef tr = Eigen::Map<const VectorXd>(tau, m.nv);
  Eigen::Map<VectorXd>(a, m.nv) = pinocchio::aba(m, d, qr, vr, tr, pinocchio::Convention::WORLD);
  Eigen::Map<Data::RowMatrixXs>(minv, m.nv, m.nv) = pinocchio::computeMinverse(m, d);
  return 0;
}

}  // extern "C"

// An importable module, so that the library is found like any other part of the package
// (integrators/native.py loads its C functions from this file).
static struct PyModuleDef module_def = {PyModuleDef_HEAD_INIT, "_aba", "Pinocchio's ABA and inverse mass matrix behind a C interface.", -1,
                                        nullptr};

PyMODINIT_FUNC PyInit__aba(void) { return PyModule_Create(&module_def); }
