// The articulated-body algorithm (and, for the soft-constraint contact, the inverse mass matrix
// from the same pass) behind a C interface, so that the simulator's compiled (numba) loops call
// them per step without a trip through Python.
//
// The model is rebuilt here from the Python model's own fields (joint types, parents,
// placements, inertias, armature, gravity; _aba_model.hpp), copied value for value. Its ABA is
// one of two, both Pinocchio's algorithm in the WORLD convention:
// - for a model of the kinematic structure _aba_cobra.c was generated for (COBRA's joints,
//   parents, placements and axes, to the bit): that file's straight-line code, which CasADi
//   generated from Pinocchio's ABA run on its symbolic scalar (tools/generate_aba.py), with the
//   model's inertias, armature and gravity as inputs. It costs about half of Pinocchio's
//   generic pass and agrees with `pin.aba` to roundoff, not to the bit (another order of the
//   same operations);
// - for any other model: the explicit instantiation that libpinocchio_default ships
//   (PINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION, the Eigen::Ref argument types of the extern
//   template), the machine code that `pin.aba` runs, so the accelerations are bit for bit those
//   of `pin.aba` on the Python model.
// The inverse mass matrix (with its acceleration) is always Pinocchio's pass, bit for bit the
// Python binding's path. tests/test_native_aba.py checks all three. Only what the simulator's
// kinematic chains hold is accepted: one free-flyer root and revolute joints (aligned with x, y,
// z or not).
#include <Python.h>

#include <cstdint>
#include <vector>

#include "pinocchio/algorithm/aba.hpp"
#include "pinocchio/multibody.hpp"

#include "_aba_model.hpp"
#include "_aba_cobra.c"  // cobra_codegen_aba and the structure it was generated for

namespace {

using Model = pinocchio::Model;
using Data = pinocchio::Data;
using VectorXd = Eigen::VectorXd;
using ConstRef = Eigen::Ref<const VectorXd>;

// A model, and whether the generated ABA serves it with these inputs: inertias (10 per
// joint), armature (nv), gravity (3).
struct Native {
  Model model;
  bool generated = false;
  std::vector<double> inertia, armature, gravity;
};

// Whether joints 1..n (code, parent, placement, axis) are those _aba_cobra.c was generated for.
bool generated_structure(int32_t n, const int32_t* code, const int32_t* parent, const double* placement,
                         const double* axis) {
  if (n != cobra_codegen_joints) return false;
  for (int32_t k = 0; k < n; ++k) {
    if (code[k] != cobra_codegen_code[k] || parent[k] != cobra_codegen_parent[k]) return false;
    for (int i = 0; i < 12; ++i)
      if (placement[12 * k + i] != cobra_codegen_placement[12 * k + i]) return false;
    for (int i = 0; i < 3; ++i)
      if (axis[3 * k + i] != cobra_codegen_axis[3 * k + i]) return false;
  }
  return true;
}

}  // namespace

extern "C" {

intptr_t cobra_model_new(int32_t n, const int32_t* code, const int32_t* parent, const double* placement,
                         const double* inertia, const double* axis, const double* armature, const double* gravity) {
  Native* native = new Native();
  if (!cobra::build_model(n, code, parent, placement, inertia, axis, armature, gravity, native->model)) {
    delete native;
    return 0;
  }
  native->generated = generated_structure(n, code, parent, placement, axis);
  native->inertia.assign(inertia, inertia + 10 * n);
  native->armature.assign(armature, armature + native->model.nv);
  native->gravity.assign(gravity, gravity + 3);
  return reinterpret_cast<intptr_t>(native);
}

void cobra_model_free(intptr_t model) { delete reinterpret_cast<Native*>(model); }

int32_t cobra_model_generated(intptr_t model) { return reinterpret_cast<Native*>(model)->generated ? 1 : 0; }

intptr_t cobra_data_new(intptr_t model) {
  return reinterpret_cast<intptr_t>(new Data(reinterpret_cast<Native*>(model)->model));
}

void cobra_data_free(intptr_t data) { delete reinterpret_cast<Data*>(data); }

int32_t cobra_aba(intptr_t model, intptr_t data, const double* q, const double* v, const double* tau, double* a) {
  const Native& n = *reinterpret_cast<Native*>(model);
  if (n.generated) {
    const double* arg[6] = {q, v, tau, n.inertia.data(), n.armature.data(), n.gravity.data()};
    double* res[1] = {a};
    return cobra_codegen_aba(arg, res, nullptr, nullptr, 0);  // stateless: no work arrays
  }
  const Model& m = n.model;
  Data& d = *reinterpret_cast<Data*>(data);
  const ConstRef qr = Eigen::Map<const VectorXd>(q, m.nq);
  const ConstRef vr = Eigen::Map<const VectorXd>(v, m.nv);
  const ConstRef tr = Eigen::Map<const VectorXd>(tau, m.nv);
  Eigen::Map<VectorXd>(a, m.nv) = pinocchio::aba(m, d, qr, vr, tr, pinocchio::Convention::WORLD);
  return 0;
}

int32_t cobra_aba_minverse(intptr_t model, intptr_t data, const double* q, const double* v, const double* tau,
                           double* a, double* minv) {
  const Model& m = reinterpret_cast<Native*>(model)->model;
  Data& d = *reinterpret_cast<Data*>(data);
  const ConstRef qr = Eigen::Map<const VectorXd>(q, m.nq);
  const ConstRef vr = Eigen::Map<const VectorXd>(v, m.nv);
  const ConstRef tr = Eigen::Map<const VectorXd>(tau, m.nv);
  Eigen::Map<VectorXd>(a, m.nv) = pinocchio::aba(m, d, qr, vr, tr, pinocchio::Convention::WORLD);
  Eigen::Map<Data::RowMatrixXs>(minv, m.nv, m.nv) = pinocchio::computeMinverse(m, d);
  return 0;
}

}  // extern "C"

static struct PyModuleDef module_def = {PyModuleDef_HEAD_INIT, "_aba",
                                        "The articulated-body algorithm and inverse mass matrix behind a C interface.",
                                        -1, nullptr};

PyMODINIT_FUNC PyInit__aba(void) { return PyModule_Create(&module_def); }
