// The compiled distance query of kinredund.geometry (issue 24). It computes what the Python path of
// kinredund/geometry/engine.py computes, with the same Pinocchio and coal calls on the same objects:
// - placements: pinocchio::updateGeometryPlacements (forward kinematics and every object's world pose);
// - the broadphase: each object's bounding spheres (centres in its joint's frame) placed by its joint, and a pair
//   kept when one of its sphere pairs is within the influence distance (compared squared, as engine.py does);
// - exact signed distances: pinocchio::computeDistance per kept pair, with the GeometryData's own requests (the
//   Python Workspace sets them: signed distances, GJK tolerance, no warm start), each from the same start
//   (fresh_distance, as engine.fresh_starts);
// - unit normals by the rules of engine.unit_normals;
// - the distance rows G[k] = n^T (J_b(p_b) - J_a(p_a)) from the world-frame joint Jacobians data.J, each body's
//   point velocity J(p) = J_v - [p]_x J_omega over the joints that support it: n^T J(p) = n^T J_v + (p x n)^T J_omega;
// - the central differences of given pairs' rows (DistanceQuery::differences, for SceneClearance.curvature): the
//   steps above for those pairs alone at q +- eps e_j.
// The model, data, geometry model and geometry data are the Python Workspace's own objects (Boost.Python),
// referenced, not copied: after a query they hold what the Python path would leave in them (a RowGuard's checks,
// on a workspace of their own, may leave the objects' poses behind the joints': DistanceQuery::place).
#include "distances.hpp"
#include "rows.hpp"

#include <boost/python.hpp>
#include <nanobind/eigen/dense.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <pinocchio/algorithm/geometry.hpp>
#include <pinocchio/algorithm/jacobian.hpp>
#include <pinocchio/algorithm/kinematics.hpp>
#include <pinocchio/collision/distance.hpp>
#include <pinocchio/multibody/data.hpp>
#include <pinocchio/multibody/model.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <tuple>
#include <vector>

namespace nb = nanobind;
namespace bp = boost::python;

namespace kinredund {
namespace {

using Model = pinocchio::Model;
using Data = pinocchio::Data;
using GeometryModel = pinocchio::GeometryModel;
using GeometryData = pinocchio::GeometryData;
using VectorXd = Eigen::VectorXd;
using VectorXl = Eigen::Matrix<std::int64_t, Eigen::Dynamic, 1>;
using RowMatrixXd = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using RowMatrixX3 = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
using Vector3 = Eigen::Vector3d;

// engine.NEAR_CONTACT: below this distance [m] a pair's normal is coal's own, not (p_b - p_a) / d
constexpr double kNearContact = 1e-6;
// engine.Workspace.lower_bounds: the sphere gap less this for rounding [m]
constexpr double kBoundSlack = 1e-9;
// the rounding allowance [m] of the coarse broadphase test (one sphere around each object's bounding spheres)
constexpr double kSphereSlack = 1e-9;
// DistanceQuery::gap: the outer spheres' gap beyond the limit [m] above which the bounding spheres' own is not sought
constexpr double kGapReach = 0.05;
// the columns of a query's output row before G's: d, unit normal (3), p_first (3), p_second (3)
constexpr Eigen::Index kColumns = 10;

using IndexArray = nb::ndarray<std::int64_t, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using OutArray = nb::ndarray<double, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using OutMap = Eigen::Map<RowMatrixXd>;

// A reference to the C++ object held by a Boost.Python instance (pin.Model, pin.Data, ...).
template <typename T>
T& extract_ref(nb::handle obj, const char* what) {
  bp::object o{bp::handle<>(bp::borrowed(obj.ptr()))};
  bp::extract<T&> ex(o);
  if (!ex.check()) throw nb::type_error((std::string("expected ") + what).c_str());
  return ex();
}

std::string str(std::size_t v) { return std::to_string(v); }

// engine.unit_normals for one pair: (p_b - p_a) / d apart; nearer, coal's normal where it is a unit vector, else
// (p_b - p_a) / |p_b - p_a| while apart, else zeros.
Vector3 unit_normal(double d, const Vector3& coal_normal, const Vector3& pa, const Vector3& pb) {
  const Vector3 diff = pb - pa;
  if (d > kNearContact) return diff / d;
  if (std::abs(coal_normal.squaredNorm() - 1.0) < 1e-6) return coal_normal;
  const double length = diff.norm();
  if (d > 0 && length > 0) return diff / length;
  return Vector3::Zero();
}

class DistanceQuery {
 public:
  DistanceQuery(nb::object model, nb::object data, nb::object geometry, nb::object gdata,
                const Eigen::Ref<const VectorXl>& joints, const Eigen::Ref<const RowMatrixX3>& centres,
                const Eigen::Ref<const VectorXd>& radii, const Eigen::Ref<const VectorXl>& first,
                const Eigen::Ref<const VectorXl>& second)
      : py_{model, data, geometry, gdata},
        model_(extract_ref<Model>(model, "a pinocchio.Model")),
        data_(extract_ref<Data>(data, "a pinocchio.Data")),
        gm_(extract_ref<GeometryModel>(geometry, "a pinocchio.GeometryModel")),
        gd_(extract_ref<GeometryData>(gdata, "a pinocchio.GeometryData")) {
    const std::size_t n = gm_.ngeoms, npairs = gm_.collisionPairs.size();
    const auto spheres = static_cast<std::size_t>(centres.rows());
    const bool per_object = n == 0 ? spheres == 0 : spheres > 0 && spheres % n == 0;
    if (static_cast<std::size_t>(joints.size()) != n || !per_object || radii.size() != centres.rows())
      throw nb::value_error(("one joint per object (" + str(n) + ") and as many bounding spheres per object (" +
                             "centres (n*m, 3), radii (n*m,)) expected; got " + str(joints.size()) + " joints, " +
                             str(centres.rows()) + " centres, " + str(radii.size()) + " radii").c_str());
    if (static_cast<std::size_t>(first.size()) != npairs || static_cast<std::size_t>(second.size()) != npairs)
      throw nb::value_error(("first and second must name the " + str(npairs) + " collision pairs").c_str());
    if (gd_.distanceRequests.size() != npairs || gd_.oMg.size() != n)
      throw nb::value_error("the geometry data was not made for this geometry model");
    if (data_.oMi.size() != static_cast<std::size_t>(model_.njoints))
      throw nb::value_error("the data was not made for this model");
    for (std::size_t k = 0; k < npairs; ++k) {
      const auto& cp = gm_.collisionPairs[k];
      if (static_cast<std::size_t>(first[k]) != cp.first || static_cast<std::size_t>(second[k]) != cp.second)
        throw nb::value_error(("pair " + str(k) + " is not the geometry model's collision pair " + str(k)).c_str());
    }
    slabs_ = n ? static_cast<Eigen::Index>(centres.rows() / n) : 0;
    centres_ = centres;
    radii_ = radii;
    world_.resize(centres.rows(), 3);
    joints_.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
      if (joints[i] < 0 || joints[i] >= model_.njoints)
        throw nb::value_error(("object " + str(i) + "'s joint " + std::to_string(joints[i]) +
                               " is not a joint of the model").c_str());
      joints_[i] = static_cast<std::size_t>(joints[i]);
    }
    outer_centres_.resize(n, 3);
    outer_world_.resize(n, 3);
    outer_radii_.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
      const auto block = centres_.middleRows(static_cast<Eigen::Index>(i) * slabs_, slabs_);
      outer_centres_.row(i) = block.colwise().mean();
      outer_radii_[i] = 0.0;
      for (Eigen::Index s = 0; s < slabs_; ++s)
        outer_radii_[i] = std::max(outer_radii_[i], (block.row(s) - outer_centres_.row(i)).norm() +
                                                      radii_[static_cast<Eigen::Index>(i) * slabs_ + s]);
    }
    first_.assign(first.data(), first.data() + npairs);
    second_.assign(second.data(), second.data() + npairs);
    // the velocity columns of the joints that move each joint's body (none for the world)
    columns_.resize(model_.njoints);
    for (int j = 1; j < model_.njoints; ++j)
      for (std::size_t s = 1; s < model_.supports[j].size(); ++s) {
        const auto t = model_.supports[j][s];
        for (int c = 0; c < model_.nvs[t]; ++c) columns_[j].push_back(model_.idx_vs[t] + c);
      }
  }

  // The pairs within `limit` [m] at q (all pairs when None) into `index` (their indices) and row by row into
  // `out`: [d [m], unit normal (3), p_first (3), p_second (3) [m]] and, with `rows`, G's row (nv) [m/rad];
  // returns how many. The caller's arrays (at least one row per pair): numpy arrays made in Python cost a
  // fraction of those returned from here. `only` (None: every pair): the pairs to consider, increasing indices;
  // each pair's numbers are the same as without it (a pair's distance and row do not depend on the others).
  std::size_t query(const Eigen::Ref<const VectorXd>& q, std::optional<double> limit, bool rows, IndexArray index,
                    OutArray out, std::optional<Eigen::Ref<const VectorXl>> only) {
    check_q(q);
    if (limit && !(*limit >= 0.0))
      throw nb::value_error(("limit must be a distance >= 0 [m] or None, got " + std::to_string(*limit)).c_str());
    if (only)
      for (Eigen::Index i = 0; i < only->size(); ++i)
        if ((*only)[i] < 0 || static_cast<std::size_t>((*only)[i]) >= first_.size() ||
            (i > 0 && (*only)[i] <= (*only)[i - 1]))
          throw nb::value_error(("only must be increasing pair indices 0.." + str(first_.size() - 1) + ", got " +
                                 std::to_string((*only)[i]) + " at " + str(static_cast<std::size_t>(i))).c_str());
    const std::size_t npairs = first_.size(), width = kColumns + (rows ? static_cast<std::size_t>(model_.nv) : 0);
    if (index.shape(0) < npairs || out.shape(0) < npairs || out.shape(1) != width)
      throw nb::value_error(("index (>= " + str(npairs) + ",) and out (>= " + str(npairs) + ", " + str(width) +
                             ") expected, got (" + str(index.shape(0)) + ",) and (" + str(out.shape(0)) + ", " +
                             str(out.shape(1)) + ")").c_str());
    nb::gil_scoped_release release;
    std::vector<std::int64_t>& ks = ks_;
    ks.clear();
    pinocchio::updateGeometryPlacements(model_, data_, gm_, gd_, q);
    if (limit) {
      place_spheres();
      if (only) {
        for (Eigen::Index i = 0; i < only->size(); ++i)
          if (near(static_cast<std::size_t>((*only)[i]), *limit)) ks.push_back((*only)[i]);
      } else {
        for (std::size_t k = 0; k < npairs; ++k)
          if (near(k, *limit)) ks.push_back(static_cast<std::int64_t>(k));
      }
    } else if (only) {
      ks.assign(only->data(), only->data() + only->size());
    } else {
      for (std::size_t k = 0; k < npairs; ++k) ks.push_back(static_cast<std::int64_t>(k));
    }
    OutMap o(out.data(), static_cast<Eigen::Index>(npairs), static_cast<Eigen::Index>(width));
    exact(ks, o);
    if (rows) distance_rows(ks, o);
    std::copy(ks.begin(), ks.end(), index.data());
    return ks.size();
  }

  // The central differences of pairs ks' rows (repeats allowed) at q [m/rad]: block j (rows j m .. j m + m - 1, m =
  // ks.size()) holds G_i(q + eps e_j) - G_i(q - eps e_j) for i = 0..m-1, from which Python takes the weighted sum
  // and the symmetric part exactly as kinredund.tracking.constraints.base.Constraint.curvature does from the rows
  // of SceneClearance._query (the same numbers). Each G_i is computed as query(q +- eps e_j, limit, rows=True)
  // computes it (placements, the pair's broadphase test at `limit`, its exact distance, unit normal and row), for
  // pair ks[i] alone; a pair beyond `limit` there gives a zero row, as it is zero in that constraint's G. The
  // objects are left placed at q - eps e_{nv-1}.
  RowMatrixXd differences(const Eigen::Ref<const VectorXd>& q, double limit, const Eigen::Ref<const VectorXl>& ks,
                          double eps) {
    check_q(q);
    const Eigen::Index nv = model_.nv, m = ks.size();
    if (model_.nq != nv) throw nb::value_error("differences needs a model with as many positions as velocities");
    if (!(limit >= 0.0) || !(eps > 0.0) || !std::isfinite(eps))
      throw nb::value_error(("limit must be a distance >= 0 [m] and eps a finite step > 0, got " +
                             std::to_string(limit) + " and " + std::to_string(eps)).c_str());
    for (Eigen::Index i = 0; i < m; ++i)
      if (ks[i] < 0 || static_cast<std::size_t>(ks[i]) >= first_.size())
        throw nb::value_error(("pair " + std::to_string(ks[i]) + " is not a pair index (0.." +
                               str(first_.size() - 1) + ")").c_str());
    RowMatrixXd D(nv * m, nv);
    nb::gil_scoped_release release;
    differences_at(q, limit, ks, eps, D);
    return D;
  }

  // differences() on checked arguments into D (nv m x nv), touching no Python object (the core's step calls it with
  // the GIL released: RowGuard::add_curvature).
  void differences_at(const Eigen::Ref<const VectorXd>& q, double limit, const Eigen::Ref<const VectorXl>& ks,
                      double eps, RowMatrixXd& D) {
    const Eigen::Index nv = model_.nv, m = ks.size();
    D.resize(nv * m, nv);
    RowMatrixXd plus(m, nv), minus(m, nv);
    VectorXd e = VectorXd::Zero(nv), at(nv);
    for (Eigen::Index j = 0; j < nv; ++j) {
      e[j] = eps;
      at = q + e;  // (as numpy's q + e: every entry, so a -0.0 becomes 0.0 alike)
      pair_rows(at, limit, ks, plus);
      at = q - e;
      pair_rows(at, limit, ks, minus);
      e[j] = 0.0;
      D.middleRows(j * m, m) = plus - minus;
    }
  }

  // The signed distances d [m] and rows G (one per entry of ks) of pairs ks at q, as query(q, limit, rows=True)
  // computes each, touching no Python object: near[i] 0 where pair ks[i] is beyond `limit` there (d[i] not written,
  // G's row zero). The core's step with rows held calls it (RowGuard::rows_at).
  void pairs_at(const Eigen::Ref<const VectorXd>& q, double limit, const Eigen::Ref<const VectorXl>& ks, VectorXd& d,
                std::vector<char>& near, RowMatrixXd& G) {
    d.resize(ks.size());
    near.assign(static_cast<std::size_t>(ks.size()), 0);
    G.resize(ks.size(), model_.nv);
    pair_rows(q, limit, ks, G, d.data(), near.data());
  }

  // For RowGuard, query's steps one pair at a time: `place` the objects at q (the joints and the bounding spheres;
  // the objects' own poses, which only coal reads, before the first `distance`), then per pair whether it is `near`
  // (query's broadphase at `limit` [m]) and its signed `distance` [m]
  void place(const Eigen::Ref<const VectorXd>& q) {
    pinocchio::forwardKinematics(model_, data_, q);
    place_spheres();
    posed_ = false;
  }
  bool near(std::size_t k, double limit) const {
    if (surely_apart(k, limit)) return false;
    const Eigen::Index m = slabs_, a = first_[k] * m, b = second_[k] * m;
    for (Eigen::Index i = 0; i < m; ++i)
      for (Eigen::Index j = 0; j < m; ++j) {
        const Vector3 diff = (world_.row(a + i) - world_.row(b + j)).transpose();
        const double reach = radii_[a + i] + radii_[b + j] + limit;
        if (diff.squaredNorm() <= reach * reach) return true;
      }
    return false;
  }
  double distance(std::size_t k) {
    if (!posed_) pinocchio::updateGeometryPlacements(model_, data_, gm_, gd_);  // (updateGeometryPlacements at q's)
    posed_ = true;
    return fresh_distance(k).min_distance;
  }
  // pinocchio::computeDistance of pair k from the same start at every call (engine.py's fresh_starts): coal 3.0.3's
  // GJK solver of a pair (the GeometryData's distance functor) starts its support-vertex search where its last call
  // ended unless the request asks for a cached guess, so the request is given GJK's default direction (1, 0, 0) and
  // support hint 0 as that guess before each call (coal writes the call's own back into it). A distance is then a
  // function of q alone, not of the queries the workspace made before (which moved it within GJK's tolerance).
  const coal::DistanceResult& fresh_distance(std::size_t k) {
    coal::DistanceRequest& request = gd_.distanceRequests[k];
    request.gjk_initial_guess = coal::GJKInitialGuess::CachedGuess;
    request.cached_gjk_guess = coal::Vec3s(1.0, 0.0, 0.0);
    request.cached_support_func_guess.setZero();
    return pinocchio::computeDistance(gm_, gd_, k);
  }
  // a lower bound [m] on the least gap between pair k's bounding spheres: the gap of the spheres around its objects
  // where that exceeds `limit` by kGapReach, else the least gap itself (both less the rounding slack)
  double gap(std::size_t k, double limit) const {
    const double outer = outer_bound(k);
    return outer > limit + kGapReach ? outer : std::max(outer, lower_bound(k));
  }

  Eigen::Index nv() const { return model_.nv; }
  std::size_t npairs() const { return first_.size(); }

  // (pair index, signed distance [m]) of the closest pair at q, the first of equals in pair order: the answer of
  // engine.Workspace.closest's Python path, from fewer exact distances. Two lower bounds on a pair's distance: the
  // gap between the spheres around its objects (outer_bound, one root per pair) and the least gap between their
  // bounding spheres (lower_bound, tighter). The pair of the least outer bound is computed first; only the pairs
  // whose outer bound does not exceed max(its distance, 0) remain (below 0 a bound says nothing about how deep two
  // objects penetrate), and they go in the order of their lower_bound until one exceeds max(least distance so
  // far, 0), which ends the search: every later pair is farther. A pair tied with the least has bounds <= the
  // least, so it is computed. The pairs computed are left active in the geometry data (gdata.activeCollisionPairs),
  // the others not; pairs whose objects have disableCollision set are skipped, as pinocchio::computeDistances
  // skips them.
  std::tuple<std::int64_t, double> closest(const Eigen::Ref<const VectorXd>& q) {
    check_q(q);
    nb::gil_scoped_release release;
    pinocchio::updateGeometryPlacements(model_, data_, gm_, gd_, q);
    const std::size_t npairs = first_.size();
    place_spheres();
    for (std::size_t k = 0; k < npairs; ++k) gd_.activeCollisionPairs[k] = false;
    std::size_t best_k = npairs;
    double best = std::numeric_limits<double>::infinity();
    auto compute = [&](std::size_t k) {
      const auto& cp = gm_.collisionPairs[k];
      if (gm_.geometryObjects[cp.first].disableCollision || gm_.geometryObjects[cp.second].disableCollision) return;
      gd_.activeCollisionPairs[k] = true;
      const double d = fresh_distance(k).min_distance;
      if (d < best || (d == best && k < best_k)) {
        best = d;
        best_k = k;
      }
    };
    // the pair of the least outer bound first: its distance rules out every pair whose outer bound exceeds it
    lb_.resize(npairs);
    std::size_t k0 = 0;
    for (std::size_t k = 0; k < npairs; ++k) {
      lb_[k] = outer_bound(k);
      if (lb_[k] < lb_[k0]) k0 = k;
    }
    if (npairs) compute(k0);
    // the others that remain, in the order of their bounding spheres' bound, until one exceeds the least distance
    order_.clear();
    for (std::size_t k = 0; k < npairs; ++k)
      if (k != k0 && lb_[k] <= std::max(best, 0.0)) order_.push_back(k);
    for (std::size_t k : order_) lb_[k] = lower_bound(k);
    std::sort(order_.begin(), order_.end(),
              [this](std::size_t a, std::size_t b) { return lb_[a] < lb_[b] || (lb_[a] == lb_[b] && a < b); });
    for (std::size_t k : order_) {
      if (lb_[k] > std::max(best, 0.0)) break;
      compute(k);
    }
    return {static_cast<std::int64_t>(best_k), best};
  }

 private:
  void check_q(const Eigen::Ref<const VectorXd>& q) const {
    if (q.size() != model_.nq)
      throw nb::value_error(("q has " + str(q.size()) + " entries, the model " + str(model_.nq)).c_str());
  }

  // every bounding sphere's centre in the world, from its joint's placement (after the placements)
  void place_spheres() {
    const Eigen::Index m = slabs_;
    for (std::size_t i = 0; i < joints_.size(); ++i) {
      const auto& M = data_.oMi[joints_[i]];
      for (Eigen::Index s = 0; s < m; ++s) {
        const Eigen::Index r = static_cast<Eigen::Index>(i) * m + s;
        world_.row(r) = (M.rotation() * centres_.row(r).transpose() + M.translation()).transpose();
      }
      outer_world_.row(i) = (M.rotation() * outer_centres_.row(i).transpose() + M.translation()).transpose();
    }
  }

  // whether the spheres around pair k's objects are farther apart than `limit` [m]: then so are all their
  // bounding spheres (each lies within its object's), with kSphereSlack [m] for rounding
  bool surely_apart(std::size_t k, double limit) const {
    const Eigen::Index a = first_[k], b = second_[k];
    const double reach = outer_radii_[a] + outer_radii_[b] + limit + kSphereSlack;
    return (outer_world_.row(a) - outer_world_.row(b)).squaredNorm() > reach * reach;
  }

  // the least gap between pair k's bounding spheres less the slack (engine.Workspace.lower_bounds)
  // the gap between the spheres around pair k's objects less the slack: a lower bound on its distance too, below
  // lower_bound(k) (each object's bounding spheres lie within its outer sphere)
  double outer_bound(std::size_t k) const {
    const Eigen::Index a = first_[k], b = second_[k];
    return (outer_world_.row(a) - outer_world_.row(b)).norm() - (outer_radii_[a] + outer_radii_[b]) - kSphereSlack;
  }

  double lower_bound(std::size_t k) const {
    const Eigen::Index m = slabs_, a = first_[k] * m, b = second_[k] * m;
    double least = std::numeric_limits<double>::infinity();
    for (Eigen::Index i = 0; i < m; ++i)
      for (Eigen::Index j = 0; j < m; ++j) {
        const double gap = (world_.row(a + i) - world_.row(b + j)).norm() - (radii_[a + i] + radii_[b + j]);
        least = std::min(least, gap);
      }
    return least - kBoundSlack;
  }

  // d, unit normal, p_first, p_second of pairs ks into the first columns of rows 0..k-1 of o
  void exact(const std::vector<std::int64_t>& ks, OutMap& o) {
    for (std::size_t r = 0; r < ks.size(); ++r) {
      const auto& res = fresh_distance(static_cast<std::size_t>(ks[r]));
      const Vector3 &pa = res.nearest_points[0], &pb = res.nearest_points[1];
      const auto i = static_cast<Eigen::Index>(r);
      o(i, 0) = res.min_distance;
      o.block<1, 3>(i, 1) = unit_normal(res.min_distance, res.normal, pa, pb).transpose();
      o.block<1, 3>(i, 4) = pa.transpose();
      o.block<1, 3>(i, 7) = pb.transpose();
    }
  }

  // G[k] = n^T (J_b(p_b) - J_a(p_a)) [m/rad] into the columns after the first kColumns of rows 0..k-1 of o, from
  // data.J after the placements' forward kinematics
  void distance_rows(const std::vector<std::int64_t>& ks, OutMap& o) {
    pinocchio::computeJointJacobians(model_, data_);
    const Eigen::Index nv = model_.nv;
    for (std::size_t r = 0; r < ks.size(); ++r) {
      const auto i = static_cast<Eigen::Index>(r);
      row(static_cast<std::size_t>(ks[r]), o.block<1, 3>(i, 1).transpose(), o.block<1, 3>(i, 4).transpose(),
          o.block<1, 3>(i, 7).transpose(), o.block(i, kColumns, 1, nv));
    }
  }

  // pair k's row n^T (J_b(p_b) - J_a(p_a)) [m/rad] into G (1 x nv), from data.J (computeJointJacobians done)
  template <typename Row>
  void row(std::size_t k, const Vector3& n, const Vector3& pa, const Vector3& pb, Row&& G) const {
    const auto& J = data_.J;  // 6 x nv, [v; omega] in world axes
    G.setZero();
    const Vector3 ma = pa.cross(n), mb = pb.cross(n);
    for (int c : columns_[joints_[first_[k]]]) G(0, c) -= n.dot(J.col(c).head<3>()) + ma.dot(J.col(c).tail<3>());
    for (int c : columns_[joints_[second_[k]]]) G(0, c) += n.dot(J.col(c).head<3>()) + mb.dot(J.col(c).tail<3>());
  }

  // the rows of pairs ks at q into G (one per entry of ks), as query(q, limit, rows=True) computes each (zero for a
  // pair beyond `limit`): the objects placed at q, each near pair's exact distance, unit normal and row
  // (and, where given, d[i] the distance and near[i] 1 for each pair within `limit`)
  void pair_rows(const Eigen::Ref<const VectorXd>& q, double limit, const Eigen::Ref<const VectorXl>& ks,
                 RowMatrixXd& G, double* d = nullptr, char* near_out = nullptr) {
    pinocchio::updateGeometryPlacements(model_, data_, gm_, gd_, q);
    place_spheres();
    bool jacobians = false;
    for (Eigen::Index i = 0; i < ks.size(); ++i) {
      const auto k = static_cast<std::size_t>(ks[i]);
      if (!near(k, limit)) {
        G.row(i).setZero();
        continue;
      }
      const auto& res = fresh_distance(k);
      const Vector3 &pa = res.nearest_points[0], &pb = res.nearest_points[1];
      const Vector3 n = unit_normal(res.min_distance, res.normal, pa, pb);
      if (d != nullptr) d[i] = res.min_distance, near_out[i] = 1;
      if (!jacobians) pinocchio::computeJointJacobians(model_, data_);
      jacobians = true;
      row(k, n, pa, pb, G.row(i));
    }
  }

  nb::object py_[4];  // keeps the Python objects (and so the references below) alive
  Model& model_;
  Data& data_;
  GeometryModel& gm_;
  GeometryData& gd_;
  Eigen::Index slabs_ = 0;
  RowMatrixX3 centres_, world_;
  VectorXd radii_;
  // one sphere around each object's bounding spheres (centre in its joint's frame, then in the world; radius)
  RowMatrixX3 outer_centres_, outer_world_;
  VectorXd outer_radii_;
  std::vector<std::size_t> joints_;
  std::vector<std::int64_t> first_, second_;
  std::vector<std::vector<int>> columns_;
  std::vector<std::int64_t> ks_;  // the pairs of the current query
  bool posed_ = true;             // after place: are the objects' poses (gdata.oMg) those at its q?
  std::vector<double> lb_;        // closest: each pair's sphere bound
  std::vector<std::size_t> order_;
};

}  // namespace

// The compiled driver's check of a step (kinredund/tracking/compiled.py, issue 27; the rows held during the step,
// where the core holds some, left out: clear_at's `held`): can a row of a SceneClearance (c_k = d_k - clearance_k,
// the pairs beyond the influence at their lower bound influence - clearance_k) be below -tol at the step's end
// (GeneralRows._row_events) or dip below it inside the step (the first test of SwitchLocation._row_dips)? The rows'
// values are lower bounds of the values that test takes from exact distances (SceneClearance.values of a fresh
// constraint), kept row by row (B the scene's motion bound,
// valid where no prismatic joint is beyond its extent: every point of the pair's objects, and of their bounding
// spheres, moves by at most B_k |dq| relative to the other):
// - row k's exact value c_k(q_k) is kept with its point q_k; at q, c_k(q) >= c_k(q_k) - B_k |q - q_k|;
// - a pair beyond the influence at q_k keeps a lower bound g_k on its sphere gap there: while g_k - B_k |q - q_k|
//   exceeds the influence it is beyond it at q too, and its value is exactly influence - clearance_k; after that
//   it is at least min(influence - clearance_k, g_k - clearance_k - B_k |q - q_k|) (the distance is at least the
//   sphere gap);
// - a lowered value at `skip` [m] or below is computed afresh at q (its pair's broadphase test and, where near, one
//   exact distance; the objects placed at q once), and where the objects are placed the rows beyond the influence
//   whose proof has used half its margin are computed afresh too (no distance), so that the proofs lapse together;
//   at the start of a step that does not start at the last one's end every row is exact;
// - a proof and the dip test below take the cheap bound max_j B_kj sum |dq| (above B_k |dq|) first, the product
//   itself where that does not decide.
// `clear` is true where every c(q1) >= -tol and every (c(q0) + c(q1) - B move) / 2 >= -tol, move = max(|q1 - q0|,
// h max(|v0|, |v1|)) + h |v1 - v0| / 4: then no row is reached and none can dip (the stepper's own search would
// find nothing). False (look in Python) otherwise, and for a q outside the box of the bound or not finite. The
// core's step calls it directly where it holds the guard (StepCore.set_guard, step.cpp), as a RowSource (rows.hpp).
class RowGuard : public RowSource {
 public:
  RowGuard(DistanceQuery& query, const Eigen::Ref<const VectorXl>& row_of_pair, const Eigen::Ref<const VectorXd>& clearances,
           double influence, const Eigen::Ref<const RowMatrixXd>& bound, const Eigen::Ref<const VectorXd>& extent,
           double tol, double skip)
      : query_(query), clearances_(clearances), bound_(bound), extent_(extent), influence_(influence), tol_(tol),
        skip_(skip) {
    const Eigen::Index size = clearances.size(), nv = query.nv();
    if (static_cast<std::size_t>(row_of_pair.size()) != query.npairs())
      throw nb::value_error(("row_of_pair needs one entry per pair (" + str(query.npairs()) + "), got " +
                             str(row_of_pair.size())).c_str());
    for (Eigen::Index k = 0; k < row_of_pair.size(); ++k)
      if (row_of_pair[k] < -1 || row_of_pair[k] >= size)
        throw nb::value_error(("row_of_pair[" + str(k) + "] must be a row (0.." + str(size) + ") or -1").c_str());
    if (size == 0 || bound.rows() != size || bound.cols() != nv || extent.size() != nv)
      throw nb::value_error(("at least one row, bound (" + str(size) + ", " + str(nv) + ") and extent (" + str(nv) +
                             ",) expected, got " + str(size) + " rows, bound (" + str(bound.rows()) + ", " +
                             str(bound.cols()) + "), extent (" + str(extent.size()) + ",)").c_str());
    if (!(influence > clearances.maxCoeff()) || !(tol >= 0.0) || !(skip >= 0.0))
      throw nb::value_error("the influence must exceed every clearance, tol and skip be >= 0 [m]");
    pair_of_row_.assign(static_cast<std::size_t>(size), -1);  // (engine.row_guard checks that no row has two)
    for (Eigen::Index k = 0; k < row_of_pair.size(); ++k)
      if (row_of_pair[k] >= 0) pair_of_row_[static_cast<std::size_t>(row_of_pair[k])] = k;
    point_of_row_.assign(static_cast<std::size_t>(size), 0);
    top_ = bound_.rowwise().maxCoeff();
    beyond_.assign(static_cast<std::size_t>(size), -std::numeric_limits<double>::infinity());
    computed_.assign(static_cast<std::size_t>(size), 0);
    drop_.assign(static_cast<std::size_t>(size), 0.0);
    kept_.resize(size);
    c0_.resize(size);
    c1_.resize(size);
    c_end_.resize(size);
    move_.resize(nv);
  }

  Eigen::Index nv() const override { return bound_.cols(); }
  Eigen::Index size() const override { return clearances_.size(); }
  bool holdable(Eigen::Index r) const override { return pair_of(r) >= 0; }
  // row r's pair in the query (-1: a row no pair gives)
  std::int64_t pair_of(Eigen::Index r) const { return pair_of_row_[static_cast<std::size_t>(r)]; }

  // For the core's step with rows held (step.cpp): rows `ks_rows`' values c and gradients G at q as
  // SceneClearance._query gives them (the rows of query(q, influence, rows=True): d - clearance within the influence,
  // influence - clearance and a zero row beyond it). Every row has a pair (StepCore.set_rows checks). No Python
  // object touched; the kept values of the checks are not changed (a check places the objects itself).
  void rows_at(const Eigen::Ref<const VectorXd>& q, const VectorXl& ks_rows, VectorXd& c, RowMatrixXd& G) override {
    const Eigen::Index a = ks_rows.size();
    query_.pairs_at(q, influence_, pairs_of(ks_rows), d_, near_, G);
    c.resize(a);
    for (Eigen::Index i = 0; i < a; ++i) {
      const double clear = clearances_[ks_rows[i]];
      c[i] = near_[static_cast<std::size_t>(i)] ? d_[i] - clear : influence_ - clear;
    }
  }

  // M += sym(H), H[:, k] = w^T D[k] / (2 eps) with D the central differences of rows `ks_rows`' gradients at q
  // (DistanceQuery::differences on their pairs at the influence, step eps: SceneClearance.curvature's, summed as
  // kinredund.tracking.constraints.base.weighted_differences sums them), no Python object touched.
  void add_curvature(const Eigen::Ref<const VectorXd>& q, const VectorXl& ks_rows, const VectorXd& w, double eps,
                     RowMatrixXd& M) override {
    query_.differences_at(q, influence_, pairs_of(ks_rows), eps, D_);
    const Eigen::Index n = nv(), a = ks_rows.size();
    const double h2 = 2.0 * eps;
    H_.resize(n, n);
    for (Eigen::Index k = 0; k < n; ++k)
      for (Eigen::Index i = 0; i < n; ++i) {
        double s = w[0] * D_(k * a, i);
        for (Eigen::Index r = 1; r < a; ++r) s += w[r] * D_(k * a + r, i);
        H_(i, k) = s / h2;
      }
    for (Eigen::Index i = 0; i < n; ++i)
      for (Eigen::Index k = 0; k < n; ++k) M(i, k) += 0.5 * (H_(i, k) + H_(k, i));
  }

  // the pairs of rows ks_rows (into pairs_)
  const VectorXl& pairs_of(const VectorXl& ks_rows) {
    pairs_.resize(ks_rows.size());
    for (Eigen::Index i = 0; i < ks_rows.size(); ++i) pairs_[i] = pair_of_row_[static_cast<std::size_t>(ks_rows[i])];
    return pairs_;
  }

  // The check itself on raw arrays of nv entries (no Python object touched). `held`: rows held during the step
  // (the stepper's active rows, on their zero), left out of both tests as the stepper's search leaves them out
  // (GeneralRows._row_events' reach and SwitchLocation._row_dips); null: none.
  bool clear_at(const double* q0p, const double* q1p, const double* v0p, const double* v1p, double h,
                const VectorXl* held) override {
    const auto start = std::chrono::steady_clock::now();
    held_ = held != nullptr && held->size() > 0 ? held : nullptr;
    const bool out = check(Eigen::Map<const VectorXd>(q0p, nv()), Eigen::Map<const VectorXd>(q1p, nv()),
                           Eigen::Map<const VectorXd>(v0p, nv()), Eigen::Map<const VectorXd>(v1p, nv()), h);
    held_ = nullptr;
    seconds_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return out;
  }

  double seconds() const { return seconds_; }
  // the smallest row value at the last check's end q1 [m] (NaN where that check stopped before its values): exact
  // where it is at or below skip (the smallest row is then computed afresh or kept exact), else a lower bound above
  // skip - SceneClearance.values' guarantee, so the record's smallest value per point needs no query of its own
  double smallest() const override { return smallest_; }
  long distances() const { return distances_; }
  long placements() const { return placements_; }
  const std::vector<long>& computed() const { return computed_; }

 private:
  bool check(const Eigen::Map<const VectorXd>& q0, const Eigen::Map<const VectorXd>& q1,
             const Eigen::Map<const VectorXd>& v0, const Eigen::Map<const VectorXd>& v1, double h) {
    smallest_ = std::numeric_limits<double>::quiet_NaN();
    if (!(h >= 0.0) || !boxed(q0) || !boxed(q1) || !v0.allFinite() || !v1.allFinite()) return false;
    values_at(q1, c1_, true);
    smallest_ = c1_.minCoeff();
    const bool reached = !(least(c1_) >= -tol_);
    if (have_end_ && q0 == q_end_)
      c0_ = c_end_;
    else  // a step from elsewhere (the first, or after a step of the Python stepper's): exact
      values_at(q0, c0_, false);
    q_end_ = q1;
    c_end_ = c1_;
    have_end_ = true;
    if (reached) return false;
    segment_move(q0, q1, v0, v1, h, move_);
    if (0.5 * least(c0_ + c1_ - top_ * move_.sum()) >= -tol_) return true;  // B_r move <= max(B_r) sum(move)
    return 0.5 * least(c0_ + c1_ - bound_ * move_) >= -tol_;
  }

  // the least entry of a row vector but the held rows' (check: they are left out of its tests)
  double least(const VectorXd& v) const { return least_but(v, held_); }

  bool boxed(const Eigen::Ref<const VectorXd>& q) const {
    return q.allFinite() && (q.cwiseAbs().array() <= extent_.array()).all();
  }

  // the rows' values at q (the class comment): row r's kept exact value where q is its point or its pair is surely
  // still beyond the influence (beyond_), else lowered to q (`lower`) while it stays above skip_, else (or without
  // `lower`) exact at q and kept. (The kept points were boxed when kept, and q is: clear checks both ends first.)
  void values_at(const Eigen::Map<const VectorXd>& q, VectorXd& c, bool lower) {
    const Eigen::Index size = c.size(), nv = q.size();
    // |q - q_p| and whether q is q_p, per kept point p (few: the rows share them)
    for (std::size_t p = 0; p < points_.size(); ++p)
      if (users_[p]) {
        gaps_[p] = (q - points_[p]).cwiseAbs();
        sums_[p] = gaps_[p].sum();
        same_[p] = q == points_[p];
      }
    bool placed = false;
    std::size_t here = points_.size();  // the kept point q (made where a row is computed at q)
    for (Eigen::Index r = 0; r < size; ++r) {
      const std::size_t i = static_cast<std::size_t>(r);
      if (have_) {
        const std::size_t p = point_of_row_[i];
        if (same_[p]) {
          c[r] = kept_[r];
          drop_[i] = 0.0;
          continue;
        }
        const double over = top_[r] * sums_[p];  // >= B_r |q - q_p|: a row surely beyond needs no more
        if (beyond_[i] - over > influence_ + kSphereSlack) {
          c[r] = kept_[r];
          drop_[i] = over;
          continue;
        }
        const double *b = bound_.data() + r * nv, *g = gaps_[p].data();  // B_r |q - q_p|
        double drop = 0.0;
        for (Eigen::Index j = 0; j < nv; ++j) drop += b[j] * g[j];
        drop_[i] = drop;
        if (beyond_[i] - drop > influence_ + kSphereSlack) {  // its spheres still beyond the influence: exact
          c[r] = kept_[r];
          continue;
        }
        if (lower) {  // (beyond the influence at q_r: the pair's distance at q is at least its sphere gap there)
          c[r] = kept_[r] - drop;
          if (beyond_[i] > -std::numeric_limits<double>::infinity())
            c[r] = std::min(kept_[r], beyond_[i] - clearances_[r] - drop);
          if (c[r] > skip_) continue;
        }
      }
      if (!placed) {
        query_.place(q);
        ++placements_;
        placed = true;
        here = new_point(q);
      }
      compute(r, near(r), here, c);
      ++computed_[i];
    }
    if (placed && lower)  // placed anyway: the rows beyond the influence whose proof has used half its margin or
      for (Eigen::Index r = 0; r < size; ++r) {  // more afresh too (no distance), so that their proofs lapse together
        const std::size_t i = static_cast<std::size_t>(r);  // later, not each at a placement of its own
        if (point_of_row_[i] != here && beyond_[i] - influence_ < 2.0 * drop_[i] && !near(r))
          compute(r, false, here, c);
      }
    have_ = true;
  }

  // is row r's pair within the influence by the broadphase (the objects placed)?
  bool near(Eigen::Index r) const {
    const std::int64_t k = pair_of_row_[static_cast<std::size_t>(r)];
    return k >= 0 && query_.near(static_cast<std::size_t>(k), influence_);
  }

  // row r exact at q (the objects placed there; `near`: its pair within the influence), kept with the kept point
  // `here` (q): -clearance + influence beyond the influence (the bound of SceneClearance._query), else the pair's
  // distance less the clearance
  void compute(Eigen::Index r, bool near, std::size_t here, VectorXd& c) {
    const std::size_t i = static_cast<std::size_t>(r);
    const std::int64_t k = pair_of_row_[i];
    c[r] = -clearances_[r] + influence_;
    beyond_[i] = -std::numeric_limits<double>::infinity();
    if (near) {
      c[r] = query_.distance(static_cast<std::size_t>(k)) - clearances_[r];
      ++distances_;
    } else {
      beyond_[i] = k < 0 ? std::numeric_limits<double>::infinity()
                         : query_.gap(static_cast<std::size_t>(k), influence_);
    }
    if (have_) --users_[point_of_row_[i]];
    point_of_row_[i] = here;
    ++users_[here];
    kept_[r] = c[r];
  }

  // a kept point for q (a free slot, or a new one), with no rows yet
  std::size_t new_point(const Eigen::Map<const VectorXd>& q) {
    std::size_t p = 0;
    while (p < points_.size() && users_[p]) ++p;
    if (p == points_.size()) {
      points_.emplace_back();
      gaps_.emplace_back();
      sums_.push_back(0.0);
      users_.push_back(0);
      same_.push_back(0);
    }
    points_[p] = q;
    gaps_[p].setZero(q.size());
    sums_[p] = 0.0;
    same_[p] = 1;
    return p;
  }

  DistanceQuery& query_;
  std::vector<std::int64_t> pair_of_row_;  // each row's pair (-1: a row no pair of the query gives)
  VectorXd clearances_;
  RowMatrixXd bound_;
  VectorXd extent_;
  double influence_, tol_, skip_;
  bool have_ = false, have_end_ = false;
  // the kept exact values, each row's point (an entry of points_, shared: users_ counts its rows; at the current
  // values_at, gaps_ |q - point| and same_ q == point), the last step's end and its values
  VectorXd kept_, q_end_, c_end_, c0_, c1_, move_;
  std::vector<std::size_t> point_of_row_;
  // per row beyond the influence at its point: a lower bound on its pair's sphere gap there [m] (its spheres move
  // apart by at most B_r |dq| too, so while gap - B_r |q - q_r| exceeds the influence, the pair is beyond it at q and
  // the row's exact value is still -clearance + influence); -inf for a row within it, inf for a row with no pair
  std::vector<double> beyond_;
  std::vector<double> drop_;  // at the current values_at: each row's B_r |q - q_r| (0 where q is q_r)
  std::vector<VectorXd> points_, gaps_;
  std::vector<double> sums_;  // at the current values_at: sum |q - point| per point
  VectorXd top_;  // each row's largest bound entry max_j B_rj: B_r |dq| <= top_r sum |dq|, the cheap first test
  std::vector<long> users_;
  std::vector<char> same_;
  double seconds_ = 0.0;  // time spent in clear_at [s]
  double smallest_ = std::numeric_limits<double>::quiet_NaN();  // smallest(): min c at the last check's end
  long distances_ = 0;    // exact distances computed
  long placements_ = 0;   // placements of the objects (forward kinematics and the bounding spheres)
  std::vector<long> computed_;  // per row, the times its value was needed afresh
  const VectorXl* held_ = nullptr;  // during clear_at: the rows left out of its tests (null: none)
  VectorXl pairs_;              // rows_at, differences_at: the rows' pairs
  VectorXd d_;                  // rows_at: their distances
  std::vector<char> near_;      // rows_at: within the influence
  RowMatrixXd D_, H_;           // add_curvature: the differences, the weighted sum
};

RowSource& row_source(nb::handle obj) {
  if (!nb::isinstance<RowSource>(obj))
    throw nb::type_error("expected a kinredund._core.RowSource (RowGuard, FrameRows, RowStack)");
  return nb::cast<RowSource&>(obj);
}

void bind_row_source(nb::module_& m) {
  nb::class_<RowSource>(m, "RowSource", "A constraint's rows as the core's step holds them (issues 27, 28).")
      .def(
          "clear",  // clear_at on checked arrays, the GIL released (every source's Python binding)
          [](RowSource& s, const Eigen::Ref<const VectorXd>& q0, const Eigen::Ref<const VectorXd>& q1,
             const Eigen::Ref<const VectorXd>& v0, const Eigen::Ref<const VectorXd>& v1, double h,
             const RowIndices& held) {
            const Eigen::Index n = s.nv();
            if (q0.size() != n || q1.size() != n || v0.size() != n || v1.size() != n)
              throw nb::value_error(("q0, q1, v0, v1 must have " + str(n) + " entries").c_str());
            for (Eigen::Index i = 0; i < held.size(); ++i)
              if (held[i] < 0 || held[i] >= s.size()) throw nb::value_error("held: rows of the source");
            nb::gil_scoped_release release;
            return s.clear_at(q0.data(), q1.data(), v0.data(), v1.data(), h, held.size() ? &held : nullptr);
          },
          nb::arg("q0"), nb::arg("q1"), nb::arg("v0"), nb::arg("v1"), nb::arg("h"), nb::arg("held") = RowIndices(),
          "the check of a step from (q0, v0) to (q1, v1), h [s] long: no row can switch within it (the rows ``held`` "
          "left out)")
      .def_prop_ro("smallest", &RowSource::smallest,
                   "the least row value at the last check's end [m] (a scene's exact at or below its skip margin, "
                   "else a lower bound; NaN where that check stopped before its values)")
      .def_prop_ro("size", &RowSource::size, "the number of rows");
}

void bind_distances(nb::module_& m) {
  nb::class_<DistanceQuery>(m, "DistanceQuery",
                            "One query of kinredund.geometry.engine.Workspace in one call (issue 24).")
      .def(nb::init<nb::object, nb::object, nb::object, nb::object, const Eigen::Ref<const VectorXl>&,
                    const Eigen::Ref<const RowMatrixX3>&, const Eigen::Ref<const VectorXd>&,
                    const Eigen::Ref<const VectorXl>&, const Eigen::Ref<const VectorXl>&>(),
           nb::arg("model"), nb::arg("data"), nb::arg("geometry"), nb::arg("gdata"), nb::arg("joints"),
           nb::arg("centres"), nb::arg("radii"), nb::arg("first"), nb::arg("second"))
      .def("query", &DistanceQuery::query, nb::arg("q"), nb::arg("limit").none(), nb::arg("rows"),
           nb::arg("index").noconvert(), nb::arg("out").noconvert(),  // written in place: never a converted copy
           nb::arg("only").none() = nb::none())
      .def("closest", &DistanceQuery::closest, nb::arg("q"))
      .def("differences", &DistanceQuery::differences, nb::arg("q"), nb::arg("limit"), nb::arg("pairs"),
           nb::arg("eps"));
  nb::class_<RowGuard, RowSource>(m, "RowGuard",
                                  "The compiled driver's check of a step for a scene's row switch (issue 27).")
      .def(nb::init<DistanceQuery&, const Eigen::Ref<const VectorXl>&, const Eigen::Ref<const VectorXd>&, double,
                    const Eigen::Ref<const RowMatrixXd>&, const Eigen::Ref<const VectorXd>&, double, double>(),
           nb::arg("query"), nb::arg("row_of_pair"), nb::arg("clearances"), nb::arg("influence"), nb::arg("bound"),
           nb::arg("extent"), nb::arg("tol"), nb::arg("skip"), nb::keep_alive<1, 2>())
      .def_prop_ro("seconds", &RowGuard::seconds, "time spent in its checks [s] (the core's calls included)")
      .def_prop_ro("distances", &RowGuard::distances, "exact distances its checks computed")
      .def_prop_ro("placements", &RowGuard::placements, "placements of the objects its checks made")
      .def_prop_ro("computed", &RowGuard::computed,
                   "per row, the times its checks needed its value afresh (placing the objects)");
}

}  // namespace kinredund
