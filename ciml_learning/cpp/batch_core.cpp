// Pinocchio over a batch of samples, as C functions (ciml_learning.core.batch_dynamics is the
// Python side): the offline path's per-sample dynamics — extraction's M q̈ + h and foot
// Jacobians, the diagnosis's regressors — in one call per batch instead of several Python
// calls per sample, whose wrappers cost more than the algorithms. And the one home of the
// contact-invariant projection's linear algebra (core/projection.py, core/extraction.py call it):
// the basis J' of eq. (8), the operator of eq. (11) and the leg coupling, per sample, where
// numpy's stacked small-matrix routines cost ~20 µs a sample.
//
// Every function takes pointers (the caller guarantees the sizes): arrays are C-contiguous
// float64 (row-major), indices int64. Each call builds its own pinocchio::Data, so calls on
// one handle may run in parallel threads (ctypes releases the GIL). No exception leaves a
// function: failures are status codes.
#include <algorithm>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Dense>
#include <Eigen/Eigenvalues>
#include <Eigen/SVD>
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
using RowMap = Eigen::Map<RowMatrix>;
using ConstRowMap = Eigen::Map<const RowMatrix>;

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

// --- the contact-invariant projection (paper §II–III); no model needed ---------------------------
//
// Shapes (row-major): foot Jacobians J (n × n_feet × 3 × nv), bases (n × nv × nv), legs (n_feet × 3:
// each foot's leg joints as indices into the n_j = nv − 6 joints), contacts (n × n_feet, 0/1). Foot i
// owns rows/columns 6+3i … 8+3i of J'; the base rows 0–5 are [I₆ 0].

// J' per sample, eq. (8): [I₆ 0] over the feet's linear Jacobians, every leg's joint block
// B_i = ∂p_i/∂q_leg,i with its singular values below gamma raised to gamma (projection.py's
// DEFAULT_GAMMA says why). A block that is not finite is left as it is (its NaN reaches Φ̃',
// whose rows extraction then refuses). Returns 0, or −2 on a leg joint out of range.
CIML_API int64_t ciml_contact_invariant_bases(int64_t n, int64_t n_feet, int64_t nv, const double* J,
                                              const int64_t* legs, double gamma, double* basis) {
  for (int64_t i = 0; i < 3 * n_feet; ++i)
    if (legs[i] < 0 || 6 + legs[i] >= nv) return -2;
  const int64_t rows = std::min<int64_t>(3 * n_feet, nv - 6);
  for (int64_t k = 0; k < n; ++k) {
    RowMap B(basis + k * nv * nv, nv, nv);
    B.setZero();
    B.topLeftCorner(6, 6).setIdentity();
    B.middleRows(6, rows) = ConstRowMap(J + k * n_feet * 3 * nv, 3 * n_feet, nv).topRows(rows);
    for (int64_t i = 0; 3 * i + 3 <= rows; ++i) {
      const int64_t* leg = legs + 3 * i;
      Eigen::Matrix3d block;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) block(r, c) = B(6 + 3 * i + r, 6 + leg[c]);
      if (!block.allFinite()) continue;
      // Most blocks are far from singular: the closed-form eigenvalues of BᵀB (~0.1 µs, against
      // ~1 µs for the SVD) show it; only within a factor 2 of γ² does the SVD decide.
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> gram;
      gram.computeDirect(block.transpose() * block, Eigen::EigenvaluesOnly);
      if (gram.eigenvalues().minCoeff() >= 2 * gamma * gamma) continue;
      const Eigen::JacobiSVD<Eigen::Matrix3d> svd(block, Eigen::ComputeFullU | Eigen::ComputeFullV);
      if (svd.singularValues().minCoeff() >= gamma) continue;  // exact: the block as it is
      block = svd.matrixU() * svd.singularValues().cwiseMax(gamma).asDiagonal() * svd.matrixV().transpose();
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) B(6 + 3 * i + r, 6 + leg[c]) = block(r, c);
    }
  }
  return 0;
}

// Eq. (11) per sample: with the constrained feet's J_cᵀ (contacts[k]) = Q [R; 0] (Householder QR)
// and Q_u the last nv − 3·n_c columns of Q, the unconstrained entries of Φ̃' are
// (Q_uᵀ J_uᵀ)⁻¹ Q_uᵀ r, J_uᵀ the columns of J'ᵀ (rows of J') of the base and the swing feet: the
// same number as (P_c J_uᵀ)⁺ P_c r (extraction.py says why), whatever basis of null(J_c) Q_u is.
// With r (n × nv) the result is phi (n × nv); with r = nullptr it is the operator O (n × nv × nv,
// Φ̃' = O r). Constrained entries are 0 and their mask (n × nv, 0/1) 0. Returns 0.
CIML_API int64_t ciml_observe(int64_t n, int64_t n_feet, int64_t nv, const double* J, const double* basis,
                              const uint8_t* contacts, const double* r, double* out, uint8_t* mask) {
  const int64_t width = r ? 1 : nv;  // right-hand sides: r, or the identity for the operator
  Eigen::MatrixXd JcT(nv, 3 * n_feet);
  Eigen::HouseholderQR<Eigen::MatrixXd> qr(nv, 3 * n_feet);
  std::vector<int64_t> unconstrained;
  for (int64_t k = 0; k < n; ++k) {
    const uint8_t* on = contacts + k * n_feet;
    const ConstRowMap Jk(J + k * n_feet * 3 * nv, 3 * n_feet, nv), Bk(basis + k * nv * nv, nv, nv);
    unconstrained.clear();
    for (int64_t e = 0; e < 6; ++e) unconstrained.push_back(e);
    int64_t n_c = 0;
    for (int64_t i = 0; i < n_feet; ++i) {
      if (on[i]) {
        JcT.middleCols(3 * n_c++, 3) = Jk.middleRows(3 * i, 3).transpose();
      } else {
        for (int64_t e = 6 + 3 * i; e < 9 + 3 * i && e < nv; ++e) unconstrained.push_back(e);
      }
    }
    const auto n_u = static_cast<int64_t>(unconstrained.size());
    // [J_uᵀ | r or I] in the coordinates of Q: its last n_u rows are [Q_uᵀ J_uᵀ | Q_uᵀ r]
    Eigen::MatrixXd M(nv, n_u + width);
    for (int64_t c = 0; c < n_u; ++c) M.col(c) = Bk.row(unconstrained[c]).transpose();
    if (r) {
      M.col(n_u) = ConstVecMap(r + k * nv, nv);
    } else {
      M.rightCols(nv).setIdentity();
    }
    if (n_c > 0) {
      qr.compute(JcT.leftCols(3 * n_c));
      M.applyOnTheLeft(qr.householderQ().adjoint());
    }
    const Eigen::MatrixXd x = M.bottomLeftCorner(n_u, n_u).partialPivLu().solve(M.bottomRightCorner(n_u, width));
    RowMap o(out + k * nv * width, nv, width);
    o.setZero();
    uint8_t* mk = mask + k * nv;
    std::fill(mk, mk + nv, uint8_t{0});
    for (int64_t c = 0; c < n_u; ++c) {
      o.row(unconstrained[c]) = x.row(c);
      mk[unconstrained[c]] = 1;
    }
  }
  return 0;
}

// The leg coupling C (n × 6 × n_j, projection.leg_coupling): C_i = (B_i⁻¹ J_i,base)ᵀ in the columns of
// leg i's joints, B_i and J_i,base the leg and base blocks of foot i's rows of J'. Returns 0, or −2
// on a leg joint out of range.
CIML_API int64_t ciml_leg_coupling(int64_t n, int64_t n_feet, int64_t nv, const double* basis, const int64_t* legs,
                                   double* C) {
  const int64_t n_j = nv - 6;
  for (int64_t i = 0; i < 3 * n_feet; ++i)
    if (legs[i] < 0 || legs[i] >= n_j || 9 + 3 * (i / 3) > nv) return -2;
  for (int64_t k = 0; k < n; ++k) {
    const ConstRowMap Bk(basis + k * nv * nv, nv, nv);
    RowMap Ck(C + k * 6 * n_j, 6, n_j);
    Ck.setZero();
    for (int64_t i = 0; i < n_feet; ++i) {
      const int64_t* leg = legs + 3 * i;
      Eigen::Matrix3d B;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) B(r, c) = Bk(6 + 3 * i + r, 6 + leg[c]);
      const Eigen::Matrix<double, 3, 6> X = B.partialPivLu().solve(Bk.block(6 + 3 * i, 0, 3, 6));
      for (int c = 0; c < 3; ++c) Ck.col(leg[c]) = X.row(c).transpose();
    }
  }
  return 0;
}

}  // extern "C"
