// kinredund._core: the Pinocchio evaluation of one frame that the compiled step (step.cpp) and the compiled IK
// (ik.cpp) share: placement, LOCAL_WORLD_ALIGNED Jacobian, kinematic Hessian and its contraction, the rotation log.
#pragma once

#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/jacobian.hpp>
#include <pinocchio/algorithm/kinematics-derivatives.hpp>
#include <pinocchio/algorithm/kinematics.hpp>
#include <pinocchio/multibody/data.hpp>
#include <pinocchio/multibody/model.hpp>

#include <Eigen/Core>

#include <cmath>

namespace kinredund {

constexpr double SMALL_ANGLE = 1e-4;  // kinredund.kinematics.closure
constexpr double NEAR_PI_SIN = 1e-6;

inline Eigen::Vector3d cross3(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return Eigen::Vector3d(a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]);
}

// log of a rotation (closure.log_scalars): w and its angle phi; false near phi = pi (the Python reference's
// symmetric-part branch, which callers hand back to Python)
inline bool rotation_log(const Eigen::Matrix3d& R, Eigen::Vector3d& w, double* angle = nullptr) {
  double vx = 0.5 * (R(2, 1) - R(1, 2)), vy = 0.5 * (R(0, 2) - R(2, 0)), vz = 0.5 * (R(1, 0) - R(0, 1));
  double c = 0.5 * (R(0, 0) + R(1, 1) + R(2, 2) - 1.0);
  double s = std::sqrt(vx * vx + vy * vy + vz * vz);
  double phi = std::atan2(s, c);
  double f;
  if (phi < SMALL_ANGLE) {
    f = 1.0 + phi * phi / 6.0;
  } else if (s > NEAR_PI_SIN) {
    f = phi / s;
  } else {
    return false;
  }
  w = Eigen::Vector3d(f * vx, f * vy, f * vz);
  if (angle != nullptr) *angle = phi;
  return true;
}

// Kinematics.jacobian_hessian: the frame's placement (data.oMf[fid]), its LOCAL_WORLD_ALIGNED Jacobian J6 (6 x nv,
// Pinocchio's [v; omega] rows) and kinematic Hessian H (Pinocchio's tensor: (a, i, k) at a + 6 (i + nv k)).
inline void frame_jacobian_hessian(const pinocchio::Model& model, pinocchio::Data& data, pinocchio::FrameIndex fid,
                                   const Eigen::Ref<const Eigen::VectorXd>& q, Eigen::MatrixXd& J6,
                                   pinocchio::Data::Tensor3x& H) {
  pinocchio::computeJointJacobians(model, data, q);
  pinocchio::updateFramePlacement(model, data, fid);
  J6.setZero(6, model.nv);
  pinocchio::getFrameJacobian(model, data, fid, pinocchio::LOCAL_WORLD_ALIGNED, J6);
  pinocchio::computeJointKinematicHessians(model, data);
  H = pinocchio::getFrameKinematicHessian(model, data, fid, pinocchio::LOCAL_WORLD_ALIGNED);
}

// sum_a mu_a dK[a, i, k] with mu in Pinocchio's [v; omega] order (HessianContraction.contract_pinocchio), n x n
template <class Out>
void contract_hessian(const pinocchio::Data::Tensor3x& H, int n, const Eigen::Matrix<double, 6, 1>& mu, Out& out) {
  out.resize(n, n);
  const double* h = H.data();
  for (int i = 0; i < n; ++i)
    for (int k = 0; k < n; ++k) {
      const double* e = h + 6 * (i + n * k);
      out(i, k) = e[0] * mu[0] + e[1] * mu[1] + e[2] * mu[2] + e[3] * mu[3] + e[4] * mu[4] + e[5] * mu[5];
    }
}

}  // namespace kinredund
