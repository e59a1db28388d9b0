// Several constraints' rows as one RowSource (rows.hpp; issue 28): the rows of a tracker with more than one general
// constraint (a scene's and a sphere's, two planes: kinredund.tracking.constraints.base.row_check), numbered as the
// stepper numbers them (GeneralRows.row_pairs: each constraint's rows after the ones before it). A step is clear where
// every part's check clears it (each part checked, so that each keeps its end's values and its smallest value), the
// rows held given to each part as its own numbers; the rows' values, gradients and curvature are their parts'.
#include <nanobind/eigen/dense.h>
#include <nanobind/stl/vector.h>

#include <algorithm>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "rows.hpp"

namespace nb = nanobind;

namespace kinredund {
namespace {

using VectorXd = Eigen::VectorXd;

class RowStack : public RowSource {
 public:
  explicit RowStack(const std::vector<nb::object>& parts) : objects_(parts) {
    if (parts.size() < 2) throw nb::value_error("a stack of rows needs at least two parts");
    Eigen::Index offset = 0;
    for (const nb::object& obj : parts) {
      RowSource& part = row_source(obj);
      if (!parts_.empty() && part.nv() != parts_[0]->nv())
        throw nb::value_error("the parts' arrays must have the same number of entries");
      parts_.push_back(&part);
      offsets_.push_back(offset);
      offset += part.size();
    }
    offsets_.push_back(offset);
    local_.resize(parts_.size());
    where_.resize(parts_.size());
  }

  Eigen::Index nv() const override { return parts_[0]->nv(); }
  Eigen::Index size() const override { return offsets_.back(); }
  bool holdable(Eigen::Index row) const override {
    const std::size_t p = part_of(row);
    return parts_[p]->holdable(row - offsets_[p]);
  }

  bool clear_at(const double* q0, const double* q1, const double* v0, const double* v1, double h,
                const RowIndices* held) override {
    split(held);
    bool clear = true;
    smallest_ = std::numeric_limits<double>::infinity();
    for (std::size_t p = 0; p < parts_.size(); ++p) {
      clear = parts_[p]->clear_at(q0, q1, v0, v1, h, local_[p].size() ? &local_[p] : nullptr) && clear;
      const double s = parts_[p]->smallest();
      smallest_ = std::isnan(s) || std::isnan(smallest_) ? std::numeric_limits<double>::quiet_NaN()
                                                         : std::min(smallest_, s);
    }
    return clear;
  }

  double smallest() const override { return smallest_; }

  void rows_at(const Eigen::Ref<const VectorXd>& q, const RowIndices& rows, VectorXd& c,
               RowMajorMatrix& G) override {
    split(&rows);
    c.resize(rows.size());
    G.resize(rows.size(), nv());
    for (std::size_t p = 0; p < parts_.size(); ++p) {
      if (!local_[p].size()) continue;
      parts_[p]->rows_at(q, local_[p], cp_, Gp_);
      for (Eigen::Index i = 0; i < local_[p].size(); ++i) {  // back to the rows' own order
        c[where_[p][static_cast<std::size_t>(i)]] = cp_[i];
        G.row(where_[p][static_cast<std::size_t>(i)]) = Gp_.row(i);
      }
    }
  }

  void add_curvature(const Eigen::Ref<const VectorXd>& q, const RowIndices& rows, const VectorXd& w, double eps,
                     RowMajorMatrix& M) override {
    split(&rows);
    for (std::size_t p = 0; p < parts_.size(); ++p) {
      if (!local_[p].size()) continue;
      wp_.resize(local_[p].size());
      for (Eigen::Index i = 0; i < local_[p].size(); ++i) wp_[i] = w[where_[p][static_cast<std::size_t>(i)]];
      parts_[p]->add_curvature(q, local_[p], wp_, eps, M);
    }
  }

 private:
  std::size_t part_of(Eigen::Index row) const {
    std::size_t p = 0;
    while (p + 1 < parts_.size() && row >= offsets_[p + 1]) ++p;
    return p;
  }

  // rows (numbers of the stack; null: none) as each part's own numbers (local_) and their places in rows (where_)
  void split(const RowIndices* rows) {
    for (std::size_t p = 0; p < parts_.size(); ++p) {
      local_[p].resize(0);
      where_[p].clear();
    }
    if (rows == nullptr) return;
    for (Eigen::Index i = 0; i < rows->size(); ++i) {
      const std::size_t p = part_of((*rows)[i]);
      where_[p].push_back(i);
    }
    for (std::size_t p = 0; p < parts_.size(); ++p) {
      local_[p].resize(static_cast<Eigen::Index>(where_[p].size()));
      for (std::size_t i = 0; i < where_[p].size(); ++i)
        local_[p][static_cast<Eigen::Index>(i)] = (*rows)[where_[p][i]] - offsets_[p];
    }
  }

  std::vector<nb::object> objects_;  // keeps the parts alive
  std::vector<RowSource*> parts_;
  std::vector<Eigen::Index> offsets_;  // each part's first row, then the number of rows
  std::vector<RowIndices> local_;
  std::vector<std::vector<Eigen::Index>> where_;
  VectorXd cp_, wp_;
  RowMajorMatrix Gp_;
  double smallest_ = std::numeric_limits<double>::quiet_NaN();
};

}  // namespace

void bind_row_stack(nb::module_& m) {
  nb::class_<RowStack, RowSource>(m, "RowStack",
                                  "Several constraints' rows (RowGuard, FrameRows) as one, numbered in turn "
                                  "(issue 28).")
      .def(nb::init<const std::vector<nb::object>&>(), nb::arg("parts"));
}

}  // namespace kinredund
