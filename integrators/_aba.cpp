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

// A model, and, when the generated ABA serves it, that code's inputs: inertias (10 per joint),
// gravity (3); empty otherwise. The armature is an argument of every call (a servo whose gear
// play is open carries none: integrators/kernels.py, gear_step).
struct Native {
  Model model;
  bool generated = false;
  std::vector<double> inertia, gravity;
};

// One rollout's workspace: Pinocchio's Data and a copy of the model whose armature the call's
// is written into before Pinocchio's pass, so that rollouts stepping on several threads at once
// with other armatures do not share a model they write.
struct Workspace {
  Model model;
  Data data;
  explicit Workspace(const Model& m) : model(m), data(m) {}
};

// `ws.model` with the armature `armature` (nv,) (written only where it differs).
const Model& with_armature(Workspace& ws, const double* armature) {
  Eigen::Map<const VectorXd> arm(armature, ws.model.nv);
  if (ws.model.armature != arm) ws.model.armature = arm;
  return ws.model;
}

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

// A Pinocchio model of `n` joints (the universe excluded), joint k with
//   code[k] (cobra::JointCode), parent[k] (0 = universe), placement[12 k ...] = rotation
//   (row-major 3x3) then translation [m] in the parent joint's frame, inertia[10 k ...] = mass
//   [kg], centre of mass (3) [m], rotational inertia about it in Pinocchio's Symmetric3 order
//   (xx, xy, yy, xz, yz, zz) [kg m^2], axis[3 k ...] = the unaligned revolute axis (unused
//   otherwise); armature (nv,) [kg m^2] and gravity (3,) [m/s^2]. Returns 0 for an unknown code.
intptr_t cobra_model_new(int32_t n, const int32_t* code, const int32_t* parent, const double* placement,
                         const double* inertia, const double* axis, const double* armature, const double* gravity) {
  Native* native = new Native();
  if (!cobra::build_model(n, code, parent, placement, inertia, axis, armature, gravity, native->model)) {
    delete native;
    return 0;
  }
  native->generated = generated_structure(n, code, parent, placement, axis);
  if (native->generated) {
    native->inertia.assign(inertia, inertia + 10 * n);
    native->gravity.assign(gravity, gravity + 3);
  }
  return reinterpret_cast<intptr_t>(native);
}

void cobra_model_free(intptr_t model) { delete reinterpret_cast<Native*>(model); }

// 1 when the model's ABA is the generated one, 0 when it is Pinocchio's.
int32_t cobra_model_generated(intptr_t model) { return reinterpret_cast<Native*>(model)->generated ? 1 : 0; }

// A workspace for `model` (Pinocchio's Data and a model copy); one per environment that steps in parallel.
intptr_t cobra_data_new(intptr_t model) {
  return reinterpret_cast<intptr_t>(new Workspace(reinterpret_cast<Native*>(model)->model));
}

void cobra_data_free(intptr_t data) { delete reinterpret_cast<Workspace*>(data); }

// The acceleration a (nv,) = ABA(q (nq,), v (nv,), tau (nv,)) of the model with the armature
// `armature` (nv,) [kg m^2] in Pinocchio's WORLD convention, as `pin.aba(model, data, q, v, tau,
// pin.Convention.WORLD)` on that model (the generated code: to roundoff).
// The joint accelerations are the LOCAL convention's to roundoff; WORLD accumulates the
// articulated inertias in the world frame, so the backward pass does not carry each one through
// its joint's placement (a 6x6 congruence per joint), and costs 12-14 % less on COBRA. Returns 0.
int32_t cobra_aba(intptr_t model, intptr_t data, const double* q, const double* v, const double* tau,
                  const double* armature, double* a) {
  const Native& n = *reinterpret_cast<Native*>(model);
  if (n.generated) {
    const double* arg[6] = {q, v, tau, n.inertia.data(), armature, n.gravity.data()};
    double* res[1] = {a};
    return cobra_codegen_aba(arg, res, nullptr, nullptr, 0);  // stateless: no work arrays
  }
  Workspace& ws = *reinterpret_cast<Workspace*>(data);
  const Model& m = with_armature(ws, armature);
  const ConstRef qr = Eigen::Map<const VectorXd>(q, m.nq);
  const ConstRef vr = Eigen::Map<const VectorXd>(v, m.nv);
  const ConstRef tr = Eigen::Map<const VectorXd>(tau, m.nv);
  Eigen::Map<VectorXd>(a, m.nv) = pinocchio::aba(m, ws.data, qr, vr, tr, pinocchio::Convention::WORLD);
  return 0;
}

// For the soft-constraint contact: the acceleration without contact a (nv,) = ABA(q, v, tau)
// and D(q)^-1 into minv (nv x nv, row-major; its upper triangle, as Pinocchio fills it) from one
// articulated-body pass of the model with the armature `armature` (nv,), as
// `pin.aba(model, data, q, v, tau, pin.Convention.WORLD)` then `pin.computeMinverse(model, data)`,
// which reuses that pass's articulated inertias: always Pinocchio's pass, generated structure or
// not. Returns 0.
int32_t cobra_aba_minverse(intptr_t model, intptr_t data, const double* q, const double* v, const double* tau,
                           const double* armature, double* a, double* minv) {
  (void)model;  // the workspace holds its copy
  Workspace& ws = *reinterpret_cast<Workspace*>(data);
  const Model& m = with_armature(ws, armature);
  const ConstRef qr = Eigen::Map<const VectorXd>(q, m.nq);
  const ConstRef vr = Eigen::Map<const VectorXd>(v, m.nv);
  const ConstRef tr = Eigen::Map<const VectorXd>(tau, m.nv);
  Eigen::Map<VectorXd>(a, m.nv) = pinocchio::aba(m, ws.data, qr, vr, tr, pinocchio::Convention::WORLD);
  Eigen::Map<Data::RowMatrixXs>(minv, m.nv, m.nv) = pinocchio::computeMinverse(m, ws.data);
  return 0;
}

}  // extern "C"

// An importable module, so that the library is found like any other part of the package
// (integrators/native.py loads its C functions from this file).
static struct PyModuleDef module_def = {PyModuleDef_HEAD_INIT, "_aba",
                                        "The articulated-body algorithm and inverse mass matrix behind a C interface.",
                                        -1, nullptr};

PyMODINIT_FUNC PyInit__aba(void) { return PyModule_Create(&module_def); }
