// The clearance of a robot frame's origin from a sphere or a plane in the core (issues 27, 28): the row of
// kinredund/tracking/constraints/clearance.py (SphereClearance, PlaneClearance) as a RowSource (rows.hpp), so that
// the core's step checks its steps for a switch and holds the row, as it does a scene's (distances.cpp's RowGuard).
// With p the frame's origin, J_p its translational Jacobian (LOCAL_WORLD_ALIGNED) and n the row's unit normal,
//   sphere: c = ||p - centre|| - radius - clearance,  n = (p - centre) / ||p - centre||,
//   plane:  c = normal^T (p - point) - clearance,       n = normal,
// grad c = n^T J_p, and the curvature sum_a n_a Hess p_a (+ J_p^T (I - n n^T) J_p / ||p - centre|| for the sphere),
// each computed with the Pinocchio calls of _FrameClearance (values: forward kinematics; rows: the frame Jacobian;
// curvature: the joint Jacobians and kinematic Hessians, frame.hpp). The check of a step is
// _FrameClearance.segment_lower_bounds's test as the stepper's search makes it (switches.SwitchLocation._row_dips):
// c at the step's end >= -tol and (c0 + c1 - L . move) / 2 >= -tol, L the frame's reach per joint (Robot.reach).
#include <nanobind/eigen/dense.h>
#include <nanobind/stl/tuple.h>

#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/kinematics.hpp>

#include <cmath>
#include <limits>
#include <string>

#include "frame.hpp"
#include "rows.hpp"

namespace nb = nanobind;

namespace kinredund {

pinocchio::Model model_from_python(nb::handle obj);  // module.cpp

namespace {

using VectorXd = Eigen::VectorXd;
using Vector3d = Eigen::Vector3d;
using CRef = Eigen::Ref<const VectorXd>;

enum Kind { SPHERE = 0, PLANE = 1 };

class FrameRows : public RowSource {
 public:
  FrameRows(nb::handle model, int frame_id, int kind, const CRef& point, const CRef& normal, double radius,
            double clearance, const CRef& reach, const CRef& extent, double tol)
      : model_(model_from_python(model)), data_(model_), fid_(frame_id), kind_(kind), radius_(radius),
        clearance_(clearance), reach_(reach), extent_(extent), tol_(tol) {
    const Eigen::Index nv = model_.nv;
    if (model_.nq != model_.nv) throw nb::value_error("a frame's rows need a model with nq == nv");
    if (frame_id < 0 || frame_id >= static_cast<int>(model_.nframes))
      throw nb::value_error(("frame id " + std::to_string(frame_id) + " out of range").c_str());
    if (kind != SPHERE && kind != PLANE) throw nb::value_error("kind must be 0 (sphere) or 1 (plane)");
    if (point.size() != 3 || normal.size() != 3 || !point.allFinite() || !normal.allFinite())
      throw nb::value_error("point and normal must be 3 finite numbers");
    if (reach.size() != nv || extent.size() != nv || !reach.allFinite() || (reach.array() < 0.0).any() ||
        extent.hasNaN() || (extent.array() < 0.0).any())
      throw nb::value_error(("reach (finite) and extent (or inf) must be " + std::to_string(nv) +
                             " numbers >= 0").c_str());
    if (!(std::isfinite(radius) && std::isfinite(clearance) && std::isfinite(tol) && clearance >= 0.0 && tol >= 0.0 &&
          (kind == PLANE || radius > 0.0)))
      throw nb::value_error("radius (> 0 for a sphere), clearance and tol (>= 0) must be finite");
    if (kind == PLANE && !(std::abs(normal.norm() - 1.0) <= 1e-12))
      throw nb::value_error("a plane's normal must be a unit vector");
    point_ = point;
    normal_ = normal;
    J6_.setZero(6, nv);
  }

  Eigen::Index nv() const override { return model_.nv; }
  Eigen::Index size() const override { return 1; }
  bool holdable(Eigen::Index row) const override { return row == 0; }
  double smallest() const override { return smallest_; }

  // The check (rows.hpp) as _FrameClearance's segment_lower_bounds gives the stepper's search its bound: none where
  // a joint is beyond its extent at an end (a prismatic joint's reach holds within it only).
  bool clear_at(const double* q0p, const double* q1p, const double* v0p, const double* v1p, double h,
                const RowIndices* held) override {
    const Eigen::Index n = nv();
    const Eigen::Map<const VectorXd> q0(q0p, n), q1(q1p, n), v0(v0p, n), v1(v1p, n);
    smallest_ = std::numeric_limits<double>::quiet_NaN();
    if (!(h >= 0.0) || !boxed(q0) || !boxed(q1) || !v0.allFinite() || !v1.allFinite()) return false;
    c1_[0] = value(q1);
    smallest_ = c1_[0];
    const bool reached = !(least_but(c1_, held) >= -tol_);
    c0_[0] = have_end_ && q0 == q_end_ ? c_end_ : value(q0);
    q_end_ = q1;
    c_end_ = c1_[0];
    have_end_ = true;
    if (reached) return false;
    segment_move(q0, q1, v0, v1, h, move_);
    low_[0] = 0.5 * (c0_[0] + c1_[0] - reach_.dot(move_));  // the row's lower bound along the step
    return least_but(low_, held) >= -tol_;
  }

  // rows_at (_FrameClearance.rows_at: c and n^T J_p from the frame Jacobian's pass). A frame at the sphere's centre
  // gives NaN (the step then hands back to Python, whose constraint says why).
  void rows_at(const Eigen::Ref<const VectorXd>& q, const RowIndices& rows, VectorXd& c,
               RowMajorMatrix& G) override {
    J6_.setZero();
    pinocchio::computeFrameJacobian(model_, data_, q, fid_, pinocchio::LOCAL_WORLD_ALIGNED, J6_);
    const Vector3d p = pinocchio::updateFramePlacement(model_, data_, fid_).translation();
    double inv;
    const Vector3d n = unit_normal(p, inv);
    c.resize(rows.size());
    G.resize(rows.size(), nv());
    for (Eigen::Index i = 0; i < rows.size(); ++i) {
      c[i] = value_at(p);
      G.row(i) = n.transpose() * J6_.topRows(3);  // n^T J_p (Pinocchio's rows [v; omega])
    }
  }

  // _FrameClearance.curvature: w0 sym(sum_a n_a Hess p_a + J_p^T (I - n n^T) J_p / ||p - centre||), w0 = sum w
  void add_curvature(const Eigen::Ref<const VectorXd>& q, const RowIndices& rows, const VectorXd& w, double,
                     RowMajorMatrix& M) override {
    const int n = static_cast<int>(nv());
    frame_jacobian_hessian(model_, data_, fid_, q, J6_, H_);  // frame.hpp
    double inv;
    const Vector3d u = unit_normal(data_.oMf[fid_].translation(), inv);
    Eigen::Matrix<double, 6, 1> mu;
    mu << u, 0.0, 0.0, 0.0;  // Pinocchio's [v; omega] order
    contract_hessian(H_, n, mu, C_);
    if (inv != 0.0) {
      const Eigen::MatrixXd Jp = J6_.topRows(3);
      const Eigen::MatrixXd Jt = Jp - u * (u.transpose() * Jp);  // (I - n n^T) J_p
      C_ += inv * (Jp.transpose() * Jt);
    }
    double w0 = 0.0;
    for (Eigen::Index i = 0; i < rows.size(); ++i) w0 += w[i];
    const double f = w0 * 0.5;
    for (int i = 0; i < n; ++i)
      for (int k = 0; k < n; ++k) M(i, k) += f * (C_(i, k) + C_(k, i));
  }

  // (c (1,), G (1, nv)) at q: rows_at of the row (for comparison with the Python constraint)
  std::tuple<VectorXd, RowMajorMatrix> rows(const CRef& q) {
    check(q);
    VectorXd c;
    RowMajorMatrix G;
    rows_at(q, RowIndices::Zero(1), c, G);
    return {c, G};
  }

  // w sum Hess c at q (nv x nv): add_curvature on zeros
  RowMajorMatrix curvature(const CRef& q, double w) {
    check(q);
    RowMajorMatrix M = RowMajorMatrix::Zero(nv(), nv());
    add_curvature(q, RowIndices::Zero(1), VectorXd::Constant(1, w), 0.0, M);
    return M;
  }

 private:
  void check(const CRef& a) const {
    if (a.size() != nv()) throw nb::value_error(("arrays of " + std::to_string(nv()) + " entries expected").c_str());
  }

  bool boxed(const Eigen::Map<const VectorXd>& q) const {
    return q.allFinite() && (q.cwiseAbs().array() <= extent_.array()).all();
  }

  // c at q from forward kinematics (_FrameClearance.values: Kinematics.pose)
  double value(const Eigen::Map<const VectorXd>& q) {
    pinocchio::forwardKinematics(model_, data_, q);
    return value_at(pinocchio::updateFramePlacement(model_, data_, fid_).translation());
  }

  // c at the frame origin p (_value)
  double value_at(const Vector3d& p) const {
    if (kind_ == PLANE) return normal_.dot(p - point_) - clearance_;
    const Vector3d d = p - point_;
    return std::sqrt(d.dot(d)) - radius_ - clearance_;
  }

  // the row's unit normal at p and the curvature factor 1 / ||p - centre|| (0 for a plane; NaN at the centre)
  Vector3d unit_normal(const Vector3d& p, double& inv) const {
    inv = 0.0;
    if (kind_ == PLANE) return normal_;
    const Vector3d d = p - point_;
    const double dist = std::sqrt(d.dot(d));
    if (!(dist > 0.0)) {
      inv = std::numeric_limits<double>::quiet_NaN();
      return Vector3d::Constant(inv);
    }
    inv = 1.0 / dist;
    return d / dist;
  }

  pinocchio::Model model_;
  pinocchio::Data data_;
  pinocchio::FrameIndex fid_;
  int kind_;
  double radius_, clearance_;
  VectorXd reach_, extent_;
  double tol_;
  Vector3d point_, normal_;  // the sphere's centre or the plane's point; the plane's unit normal
  Eigen::MatrixXd J6_;
  pinocchio::Data::Tensor3x H_;
  Eigen::MatrixXd C_;
  VectorXd move_;
  VectorXd c0_ = VectorXd::Zero(1), c1_ = VectorXd::Zero(1), low_ = VectorXd::Zero(1);
  VectorXd q_end_;
  double c_end_ = 0.0;
  bool have_end_ = false;
  double smallest_ = std::numeric_limits<double>::quiet_NaN();
};

}  // namespace

void bind_frame_rows(nb::module_& m) {
  nb::class_<FrameRows, RowSource>(m, "FrameRows",
                                   "The clearance row of a robot frame's origin from a sphere or a plane, as the "
                                   "core's step checks and holds it (issue 28).")
      .def(nb::init<nb::handle, int, int, const CRef&, const CRef&, double, double, const CRef&, const CRef&,
                    double>(),
           nb::arg("model"), nb::arg("frame_id"), nb::arg("kind"), nb::arg("point"), nb::arg("normal"),
           nb::arg("radius"), nb::arg("clearance"), nb::arg("reach"), nb::arg("extent"), nb::arg("tol"))
      .def("rows", &FrameRows::rows, nb::arg("q"))
      .def("curvature", &FrameRows::curvature, nb::arg("q"), nb::arg("w"));
}

}  // namespace kinredund
