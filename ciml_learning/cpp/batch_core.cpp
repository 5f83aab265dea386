// Pinocchio over a batch of samples, as C functions (ciml_learning.core.batch_dynamics is the
// Python side): the offline path's per-sample dynamics — extraction's M q̈ + h and foot
// Jacobians, the diagnosis's regressors — in one call per batch instead of several Python
// calls per sample, whose wrappers cost more than the algorithms.
//
// Every function takes pointers (the caller guarantees the sizes): arrays are C-contiguous
// float64 (row-major), indices int64. Each call builds its own pinocchio::Data, so calls on
// one handle may run in parallel threads (ctypes releases the GIL). No exception leaves a
// function: failures are status codes.
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <pinocchio/multibody.hpp>
#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/jacobian.hpp>
#include <pinocchio/algorithm/kinematics.hpp>
#include <pinocchio/algorithm/regressor.hpp>
#include <pinocchio/algorithm/rnea.hpp>
#include <pinocchio/algorithm/rnea-derivatives.hpp>
#include <pinocchio/serialization.hpp>

namespace {

using RowMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using ConstVecMap = Eigen::Map<const Eigen::VectorXd>;
using VecMap = Eigen::Map<Eigen::VectorXd>;

struct Batch {
  pinocchio::Model model;
  std::vector<pinocchio::FrameIndex> feet;
};

// The linear rows of each foot frame's Jacobian (LOCAL_WORLD_ALIGNED) at the kinematics data
// holds (computeJointJacobians, updateFramePlacements) into J (n_feet × 3 × nv).
void foot_jacobians(const Batch& b, pinocchio::Data& data, pinocchio::Data::Matrix6x& J6, double* J) {
  const auto nv = b.model.nv;
  for (size_t i = 0; i < b.feet.size(); ++i) {
    J6.setZero();
    pinocchio::getFrameJacobian(b.model, data, b.feet[i], pinocchio::LOCAL_WORLD_ALIGNED, J6);
    Eigen::Map<RowMatrix>(J + i * 3 * nv, 3, nv) = J6.topRows<3>();
  }
}

}  // namespace

#define CIML_API __attribute__((visibility("default")))

extern "C" {

// A Pinocchio model from its text archive (pinocchio.Model.saveToString, NUL-terminated) and
// the foot frames; nullptr if the archive does not load or a frame index is out of range.
CIML_API void* ciml_batch_new(const char* archive, const int64_t* feet, int64_t n_feet) {
  auto b = std::make_unique<Batch>();
  try {
    b->model.loadFromString(std::string(archive));
    for (int64_t i = 0; i < n_feet; ++i) {
      if (feet[i] < 0 || feet[i] >= static_cast<int64_t>(b->model.nframes)) return nullptr;
      b->feet.push_back(static_cast<pinocchio::FrameIndex>(feet[i]));
    }
  } catch (...) {
    return nullptr;
  }
  return b.release();
}

CIML_API void ciml_batch_free(void* h) { delete static_cast<Batch*>(h); }

// Per sample k of n: tau[k] = RNEA(q, v, a) = M q̈ + h (nv) and J[k] (n_feet × 3 × nv, the
// feet's linear Jacobians, LOCAL_WORLD_ALIGNED). Returns 0, or −1 on an exception.
CIML_API int64_t ciml_batch_inverse_dynamics(void* h, int64_t n, const double* q, const double* v, const double* a,
                                             double* tau, double* J) {
  const auto& b = *static_cast<Batch*>(h);
  const auto nq = b.model.nq, nv = b.model.nv;
  const auto nf = static_cast<int64_t>(b.feet.size());
  try {
    pinocchio::Data data(b.model);
    pinocchio::Data::Matrix6x J6 = pinocchio::Data::Matrix6x::Zero(6, nv);
    for (int64_t k = 0; k < n; ++k) {
      const ConstVecMap qk(q + k * nq, nq);
      VecMap(tau + k * nv, nv) = pinocchio::rnea(b.model, data, qk, ConstVecMap(v + k * nv, nv),
                                                 ConstVecMap(a + k * nv, nv));
      pinocchio::computeJointJacobians(b.model, data, qk);
      pinocchio::updateFramePlacements(b.model, data);
      foot_jacobians(b, data, J6, J + k * nf * 3 * nv);
    }
  } catch (...) {
    return -1;
  }
  return 0;
}

// Per sample k of n: J[k] as ciml_batch_inverse_dynamics, Y[k] (nv × 10·(njoints − 1), the joint
// torque regressor: RNEA = Y π of the bodies' inertial parameters) and D[k] (nv × nv, ∂RNEA/∂q).
CIML_API int64_t ciml_batch_regressors(void* h, int64_t n, const double* q, const double* v, const double* a,
                                       double* J, double* Y, double* D) {
  const auto& b = *static_cast<Batch*>(h);
  const auto nq = b.model.nq, nv = b.model.nv;
  const auto nf = static_cast<int64_t>(b.feet.size());
  const int64_t np = 10 * (b.model.njoints - 1);
  try {
    pinocchio::Data data(b.model);
    pinocchio::Data::Matrix6x J6 = pinocchio::Data::Matrix6x::Zero(6, nv);
    for (int64_t k = 0; k < n; ++k) {
      const ConstVecMap qk(q + k * nq, nq), vk(v + k * nv, nv), ak(a + k * nv, nv);
      pinocchio::computeJointJacobians(b.model, data, qk);
      pinocchio::updateFramePlacements(b.model, data);
      foot_jacobians(b, data, J6, J + k * nf * 3 * nv);
      Eigen::Map<RowMatrix>(Y + k * nv * np, nv, np) =
          pinocchio::computeJointTorqueRegressor(b.model, data, qk, vk, ak);
      data.dtau_dq.setZero();
      pinocchio::computeRNEADerivatives(b.model, data, qk, vk, ak);
      Eigen::Map<RowMatrix>(D + k * nv * nv, nv, nv) = data.dtau_dq;
    }
  } catch (...) {
    return -1;
  }
  return 0;
}

// For m items i: out[i] (nv) = ∂J_f/∂q_d ᵀ λ_i, the linear rows of foot f's Jacobian
// (LOCAL_WORLD_ALIGNED) differentiated along the unit velocity e_d at q[sample[i]]
// (computeJointJacobiansTimeVariation with v = e_d), times the force λ_i (3). foot[i] indexes
// the feet given to ciml_batch_new, dof[i] the velocity coordinates. Returns 0, −1 on an
// exception, −2 on an index out of range.
CIML_API int64_t ciml_batch_jacobian_variation_products(void* h, int64_t m, const int64_t* sample, const int64_t* foot,
                                                        const int64_t* dof, const double* q, int64_t n_samples,
                                                        const double* lam, double* out) {
  const auto& b = *static_cast<Batch*>(h);
  const auto nq = b.model.nq, nv = b.model.nv;
  const auto nf = static_cast<int64_t>(b.feet.size());
  try {
    pinocchio::Data data(b.model);
    pinocchio::Data::Matrix6x dJ = pinocchio::Data::Matrix6x::Zero(6, nv);
    Eigen::VectorXd unit = Eigen::VectorXd::Zero(nv);
    for (int64_t i = 0; i < m; ++i) {
      if (sample[i] < 0 || sample[i] >= n_samples || foot[i] < 0 || foot[i] >= nf || dof[i] < 0 || dof[i] >= nv)
        return -2;
      unit.setZero();
      unit[dof[i]] = 1.0;
      pinocchio::computeJointJacobiansTimeVariation(b.model, data, ConstVecMap(q + sample[i] * nq, nq), unit);
      dJ.setZero();
      pinocchio::getFrameJacobianTimeVariation(b.model, data, b.feet[foot[i]], pinocchio::LOCAL_WORLD_ALIGNED, dJ);
      VecMap(out + i * nv, nv) = dJ.topRows<3>().transpose() * Eigen::Map<const Eigen::Vector3d>(lam + 3 * i);
    }
  } catch (...) {
    return -1;
  }
  return 0;
}

}  // extern "C"
