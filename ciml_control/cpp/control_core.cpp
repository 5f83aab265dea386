// The controller's calls into Pinocchio and proxsuite as C functions, for the compiled
// (numba) modules of ciml_control.compiled (control_step, feedforward_qp, leg_ik), which call
// them by address through ciml_control.native (ccall): no Python between the two Pinocchio
// passes, the QP and the algebra of one 250 Hz step.
//
// ciml_control.native is the Python side: it loads this library, wraps the handles
// (Dynamics, QpSolvers) and lists the ABI of the functions compiled code calls (FUNCTIONS).
// Every function takes only pointers (the caller guarantees the sizes): matrices are
// row-major float64, sizes and results int64. No exception leaves a function: failures are
// status codes.
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <tuple>
#include <vector>

#include <pinocchio/multibody.hpp>
#include <pinocchio/algorithm/compute-all-terms.hpp>
#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/jacobian.hpp>
#include <pinocchio/algorithm/kinematics.hpp>
#include <pinocchio/algorithm/joint-configuration.hpp>
#include <pinocchio/serialization.hpp>
#include <proxsuite/proxqp/dense/dense.hpp>

namespace {

using RowMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using ConstRowMap = Eigen::Map<const RowMatrix>;
using ConstVecMap = Eigen::Map<const Eigen::VectorXd>;
using VecMap = Eigen::Map<Eigen::VectorXd>;

struct Dynamics {
  pinocchio::Model model;
  std::unique_ptr<pinocchio::Data> data;
  std::vector<pinocchio::FrameIndex> feet;
  pinocchio::Data::Matrix6x J6;
  Eigen::VectorXd dq;
};

using Size = std::tuple<int64_t, int64_t, int64_t, bool>;  // (n, n_eq, n_in, box)

struct Solver {
  std::unique_ptr<proxsuite::proxqp::dense::QP<double>> qp;
  Eigen::MatrixXd H;  // the cost it holds
  Eigen::VectorXd g;
};

struct QpSolvers {
  double eps_abs;
  int64_t max_iter;
  std::map<Size, Solver> by_size;
};

}  // namespace

// Only these functions are exported (built with -fvisibility=hidden): the process also holds
// Pinocchio's own libraries, whose template instances must not bind to these.
#define CIML_API __attribute__((visibility("default")))

extern "C" {

// A Pinocchio model from its text archive (pinocchio.Model.saveToString, NUL-terminated)
// and the foot frames; nullptr if the archive does not load.
CIML_API void* ciml_dynamics_new(const char* archive, const int64_t* feet, const int64_t* n_feet) {
  auto d = std::make_unique<Dynamics>();
  try {
    d->model.loadFromString(std::string(archive));
    d->data = std::make_unique<pinocchio::Data>(d->model);
    for (int64_t i = 0; i < *n_feet; ++i) {
      if (feet[i] < 0 || feet[i] >= static_cast<int64_t>(d->model.nframes)) return nullptr;
      d->feet.push_back(static_cast<pinocchio::FrameIndex>(feet[i]));
    }
  } catch (...) {
    return nullptr;
  }
  d->J6 = pinocchio::Data::Matrix6x::Zero(6, d->model.nv);
  d->dq = Eigen::VectorXd::Zero(d->model.nv);
  return d.release();
}

CIML_API void ciml_dynamics_free(void* h) { delete static_cast<Dynamics*>(h); }

// One Pinocchio pass at (q, v): M (nv × nv, upper triangle as CRBA fills it), h (nv, the
// nonlinear effects) and J (n_feet × 3 × nv, the linear part of each foot frame's
// Jacobian, LOCAL_WORLD_ALIGNED).
CIML_API void ciml_terms(void* h, const double* q, const double* v, double* M, double* nle, double* J) {
  auto* d = static_cast<Dynamics*>(h);
  const auto nv = d->model.nv;
  pinocchio::computeAllTerms(d->model, *d->data, ConstVecMap(q, d->model.nq), ConstVecMap(v, nv));
  pinocchio::updateFramePlacements(d->model, *d->data);
  Eigen::Map<RowMatrix>(M, nv, nv) = d->data->M;
  VecMap(nle, nv) = d->data->nle;
  for (size_t i = 0; i < d->feet.size(); ++i) {
    d->J6.setZero();
    pinocchio::getFrameJacobian(d->model, *d->data, d->feet[i], pinocchio::LOCAL_WORLD_ALIGNED, d->J6);
    Eigen::Map<RowMatrix>(J + i * 3 * nv, 3, nv) = d->J6.topRows<3>();
  }
}

// Forward kinematics at q: J (n_feet × 3 × nv) as ciml_terms and each foot frame's world
// position into feet (n_feet × 3) — one Newton iteration's kinematics of the leg IK.
CIML_API void ciml_foot_kinematics(void* h, const double* q, double* J, double* feet) {
  auto* d = static_cast<Dynamics*>(h);
  const auto nv = d->model.nv;
  pinocchio::computeJointJacobians(d->model, *d->data, ConstVecMap(q, d->model.nq));
  pinocchio::updateFramePlacements(d->model, *d->data);
  for (size_t i = 0; i < d->feet.size(); ++i) {
    d->J6.setZero();
    pinocchio::getFrameJacobian(d->model, *d->data, d->feet[i], pinocchio::LOCAL_WORLD_ALIGNED, d->J6);
    Eigen::Map<RowMatrix>(J + i * 3 * nv, 3, nv) = d->J6.topRows<3>();
    VecMap(feet + 3 * i, 3) = d->data->oMf[d->feet[i]].translation();
  }
}

// Each foot frame's classical acceleration (world-aligned, linear) at (q, v, a) into
// out (n_feet × 3): with a's joint part zero, the foot acceleration the base motion and
// the velocities alone produce.
CIML_API void ciml_foot_acceleration(void* h, const double* q, const double* v, const double* a, double* out) {
  auto* d = static_cast<Dynamics*>(h);
  const auto nq = d->model.nq, nv = d->model.nv;
  pinocchio::forwardKinematics(d->model, *d->data, ConstVecMap(q, nq), ConstVecMap(v, nv), ConstVecMap(a, nv));
  pinocchio::updateFramePlacements(d->model, *d->data);
  for (size_t i = 0; i < d->feet.size(); ++i)
    VecMap(out + 3 * i, 3) =
        pinocchio::getFrameClassicalAcceleration(d->model, *d->data, d->feet[i], pinocchio::LOCAL_WORLD_ALIGNED).linear();
}

// out (nv) = q1 ⊖ q0 (pinocchio::difference: base part in q0's base frame).
CIML_API void ciml_difference(void* h, const double* q0, const double* q1, double* out) {
  auto* d = static_cast<Dynamics*>(h);
  pinocchio::difference(d->model, ConstVecMap(q0, d->model.nq), ConstVecMap(q1, d->model.nq), d->dq);
  VecMap(out, d->model.nv) = d->dq;
}

CIML_API void* ciml_qp_new(const double* eps_abs, const int64_t* max_iter) {
  auto* s = new QpSolvers();
  s->eps_abs = *eps_abs;
  s->max_iter = *max_iter;
  return s;
}

CIML_API void ciml_qp_free(void* h) { delete static_cast<QpSolvers*>(h); }

// Forget the solver of a size (sizes = n, n_eq, n_in, box).
CIML_API void ciml_qp_drop(void* h, const int64_t* sizes) {
  static_cast<QpSolvers*>(h)->by_size.erase({sizes[0], sizes[1], sizes[2], sizes[3] != 0});
}

// How many solvers are kept (one per problem size).
CIML_API void ciml_qp_count(void* h, int64_t* out) { *out = static_cast<int64_t>(static_cast<QpSolvers*>(h)->by_size.size()); }

// min ½xᵀHx + gᵀx  s.t.  Ax = b, l ≤ Cx ≤ u, lb ≤ x ≤ ub  (sizes = n, n_eq, n_in, box:
// 0 for a problem without the bounds lb, ub, which are then not read).
// One proxsuite dense solver per size, created on first use and updated in place after;
// every solve starts from the equality-constrained initial guess. x (n) and
// info = (status, iterations) out: status 0 solved, −1 an exception, else proxsuite's
// QPSolverOutput + 1. A solver that failed is dropped.
CIML_API void ciml_qp_solve(void* h, const int64_t* sizes, const double* H, const double* g, const double* A,
                   const double* b, const double* C, const double* l, const double* u, const double* lb,
                   const double* ub, double* x, int64_t* info) {
  using namespace proxsuite::proxqp;
  auto* s = static_cast<QpSolvers*>(h);
  const int64_t n = sizes[0], n_eq = sizes[1], n_in = sizes[2];
  const bool box = sizes[3] != 0;
  const Size key{n, n_eq, n_in, box};
  info[0] = -1;
  info[1] = 0;
  try {
    const Eigen::MatrixXd Hm = ConstRowMap(H, n, n), Am = ConstRowMap(A, n_eq, n), Cm = ConstRowMap(C, n_in, n);
    const Eigen::VectorXd gv = ConstVecMap(g, n), bv = ConstVecMap(b, n_eq), lv = ConstVecMap(l, n_in),
                          uv = ConstVecMap(u, n_in);
    const Eigen::VectorXd lbv = box ? Eigen::VectorXd(ConstVecMap(lb, n)) : Eigen::VectorXd(),
                          ubv = box ? Eigen::VectorXd(ConstVecMap(ub, n)) : Eigen::VectorXd();
    auto it = s->by_size.find(key);
    if (it == s->by_size.end()) {
      Solver fresh{std::make_unique<dense::QP<double>>(n, n_eq, n_in, box), Hm, gv};
      auto& st = fresh.qp->settings;
      st.eps_abs = s->eps_abs;
      st.eps_rel = 0.0;
      st.max_iter = s->max_iter;
      st.verbose = false;
      st.initial_guess = InitialGuessStatus::EQUALITY_CONSTRAINED_INITIAL_GUESS;
      if (box)
        fresh.qp->init(Hm, gv, Am, bv, Cm, lv, uv, lbv, ubv);
      else
        fresh.qp->init(Hm, gv, Am, bv, Cm, lv, uv);
      it = s->by_size.emplace(key, std::move(fresh)).first;
    } else if (it->second.H == Hm && it->second.g == gv) {
      if (box)
        it->second.qp->update(std::nullopt, std::nullopt, Am, bv, Cm, lv, uv, lbv, ubv);
      else
        it->second.qp->update(std::nullopt, std::nullopt, Am, bv, Cm, lv, uv);
    } else {
      if (box)
        it->second.qp->update(Hm, gv, Am, bv, Cm, lv, uv, lbv, ubv);
      else
        it->second.qp->update(Hm, gv, Am, bv, Cm, lv, uv);
      it->second.H = Hm;
      it->second.g = gv;
    }
    auto& qp = *it->second.qp;
    qp.solve();
    const auto status = qp.results.info.status;
    info[0] = status == QPSolverOutput::PROXQP_SOLVED ? 0 : static_cast<int64_t>(status) + 1;
    info[1] = static_cast<int64_t>(qp.results.info.iter);
    VecMap(x, n) = qp.results.x;
  } catch (...) {
    info[0] = -1;
  }
  if (info[0] != 0) s->by_size.erase(key);
}

}  // extern "C"
