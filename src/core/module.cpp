// kinredund._core: the compiled core (issue 28). The Python package works without it (Python stepper).
#include "distances.hpp"
#include "loop.hpp"
#include "paths.hpp"
#include "record_checks.hpp"
#include "rows.hpp"

#include <boost/python.hpp>
#include <nanobind/nanobind.h>
#include <nanobind/eigen/dense.h>
#include <nanobind/stl/tuple.h>

#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/jacobian.hpp>
#include <pinocchio/algorithm/kinematics.hpp>
#include <pinocchio/algorithm/kinematics-derivatives.hpp>
#include <pinocchio/multibody/data.hpp>
#include <pinocchio/multibody/model.hpp>

#include <stdexcept>
#include <string>

#include "frame.hpp"
#include "ik.hpp"
#include "step.hpp"
#include "watch.hpp"

namespace nb = nanobind;
namespace bp = boost::python;

namespace kinredund {

using Model = pinocchio::Model;
using Data = pinocchio::Data;
using MatrixXd = Eigen::MatrixXd;
using VectorXd = Eigen::VectorXd;
using RowMatrixXd = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// A copy of a Python `pin.Model` (a Boost.Python object) as a C++ Model.
Model model_from_python(nb::handle obj) {
  bp::object o{bp::handle<>(bp::borrowed(obj.ptr()))};
  bp::extract<Model&> ex(o);
  if (!ex.check()) throw nb::type_error("expected a pinocchio.Model (pin.Model)");
  return Model(ex());
}

// The C++ Model of a Python `pin.Model`, not copied: valid while the Python object lives (the caller keeps it).
const Model& model_ref_from_python(nb::handle obj) {
  bp::object o{bp::handle<>(bp::borrowed(obj.ptr()))};
  bp::extract<Model&> ex(o);
  if (!ex.check()) throw nb::type_error("expected a pinocchio.Model (pin.Model)");
  return ex();
}

// The kinematics of one frame: placement, LOCAL_WORLD_ALIGNED Jacobian and kinematic Hessian.
class Kinematics {
 public:
  Kinematics(nb::handle model, int frame_id) : model_(model_from_python(model)), data_(model_), fid_(frame_id) {
    if (frame_id < 0 || frame_id >= static_cast<int>(model_.nframes))
      throw nb::value_error(("frame id " + std::to_string(frame_id) + " out of range [0, " +
                             std::to_string(model_.nframes) + ")").c_str());
    J_.setZero(6, model_.nv);
  }
  int nq() const { return model_.nq; }
  int nv() const { return model_.nv; }

  // (T 4x4, J 6 x nv, H 6 x nv*nv with H[a, i*nv + k] = dJ[a, i] / dq_k (the layout-fixed pin Hessian, shared/STACK.md)).
  std::tuple<RowMatrixXd, RowMatrixXd, RowMatrixXd> jacobian_hessian(const Eigen::Ref<const VectorXd>& q) {
    check_q(q);
    pinocchio::Data::Tensor3x H;
    frame_jacobian_hessian(model_, data_, fid_, q, J_, H);  // frame.hpp
    const auto& M = data_.oMf[fid_];
    RowMatrixXd Hm(6, model_.nv * model_.nv);
    const Eigen::DenseIndex nv = model_.nv;
    for (Eigen::DenseIndex a = 0; a < 6; ++a)
      for (Eigen::DenseIndex i = 0; i < nv; ++i)
        for (Eigen::DenseIndex k = 0; k < nv; ++k) Hm(a, i * nv + k) = H(a, i, k);
    return {M.toHomogeneousMatrix(), J_, Hm};
  }

 private:
  void check_q(const Eigen::Ref<const VectorXd>& q) const {
    if (q.size() != model_.nq)
      throw nb::value_error(("q has " + std::to_string(q.size()) + " entries, the model " +
                             std::to_string(model_.nq)).c_str());
  }
  Model model_;
  Data data_;
  pinocchio::FrameIndex fid_;
  MatrixXd J_;
};

}  // namespace kinredund

NB_MODULE(_core, m) {
  m.doc() = "kinredund's compiled core (issue 28): Pinocchio called from C++.";
  m.attr("pinocchio_version") = KINREDUND_PIN_VERSION;
  nb::class_<kinredund::Kinematics>(m, "Kinematics")
      .def(nb::init<nb::handle, int>(), nb::arg("model"), nb::arg("frame_id"))
      .def_prop_ro("nq", &kinredund::Kinematics::nq)
      .def_prop_ro("nv", &kinredund::Kinematics::nv)
      .def("jacobian_hessian", &kinredund::Kinematics::jacobian_hessian, nb::arg("q"));
  kinredund::bind_step(m);
  kinredund::bind_ik(m);
  kinredund::bind_row_source(m);
  kinredund::bind_distances(m);
  kinredund::bind_frame_rows(m);
  kinredund::bind_row_stack(m);
  kinredund::bind_loop(m);
  kinredund::bind_watch(m);
  kinredund::bind_paths(m);
  kinredund::bind_record_checks(m);
}
