#include "testing/ransac_examples.hpp"

#include <Eigen/Eigenvalues>
#include <cmath>

namespace line_odom {
namespace {

class Line2DEstimator {
 public:
  using Model = Eigen::Vector3d;
  static constexpr int kSampleSize = 2;
  static constexpr int kMaxModels = 1;

  Line2DEstimator(const std::vector<Eigen::Vector2d>& points, const std::vector<double>& weights, double threshold)
      : points_(points), weights_(weights), threshold_(threshold) {
    for (size_t i = 0; i < points.size(); ++i) total_ += weight(i);
  }
  int num_data() const { return static_cast<int>(points_.size()); }
  int generate(const int* sample, Model* models) const {
    const Eigen::Vector2d p = points_[sample[0]], q = points_[sample[1]];
    const Eigen::Vector2d d = q - p;
    if (!(d.norm() > 1e-12)) return 0;
    const Eigen::Vector2d n(-d.y() / d.norm(), d.x() / d.norm());
    models[0] = Eigen::Vector3d(n.x(), n.y(), -n.dot(p));
    return 1;
  }
  RansacScore score(const Model& l, double /*to_beat*/) const {
    RansacScore sc;
    sc.value = 0.0;
    for (size_t i = 0; i < points_.size(); ++i) {
      if (std::abs(l.x() * points_[i].x() + l.y() * points_[i].y() + l.z()) < threshold_) {
        sc.value += weight(i);
        ++sc.inliers;
      }
    }
    sc.inlier_fraction[0] = total_ > 0.0 ? sc.value / total_ : 0.0;
    return sc;
  }
  // Local optimisation: weighted total least squares on the inliers.
  void refine(Model* l) const {
    double w_sum = 0.0;
    Eigen::Vector2d mean = Eigen::Vector2d::Zero();
    for (size_t i = 0; i < points_.size(); ++i)
      if (inlier(*l, i)) w_sum += weight(i), mean += weight(i) * points_[i];
    if (!(w_sum > 0.0)) return;
    mean /= w_sum;
    Eigen::Matrix2d C = Eigen::Matrix2d::Zero();
    for (size_t i = 0; i < points_.size(); ++i)
      if (inlier(*l, i)) C += weight(i) * (points_[i] - mean) * (points_[i] - mean).transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(C);
    const Eigen::Vector2d n = es.eigenvectors().col(0);
    if (n.allFinite()) *l = Eigen::Vector3d(n.x(), n.y(), -n.dot(mean));
  }

 private:
  double weight(size_t i) const { return weights_.empty() ? 1.0 : weights_[i]; }
  bool inlier(const Model& l, size_t i) const {
    return std::abs(l.x() * points_[i].x() + l.y() * points_[i].y() + l.z()) < threshold_;
  }
  const std::vector<Eigen::Vector2d>& points_;
  const std::vector<double>& weights_;
  double threshold_;
  double total_ = 0.0;
};

class Translation2DEstimator {
 public:
  using Model = Eigen::Vector2d;
  static constexpr int kNumDataTypes = 2;
  static constexpr int kNumSolvers = 2;
  static constexpr int kMaxSampleSize = 2;
  static constexpr int kMaxModels = 1;

  Translation2DEstimator(const std::vector<Eigen::Vector2d>& pa, const std::vector<Eigen::Vector2d>& pb,
                         const std::vector<Eigen::Vector2d>& u, const std::vector<double>& o, double threshold)
      : pa_(pa), pb_(pb), u_(u), o_(o), threshold_(threshold) {}

  int num_data(int type) const { return static_cast<int>(type == 0 ? pa_.size() : u_.size()); }
  int sample_size(int solver, int type) const { return solver == type ? (solver == 0 ? 1 : 2) : 0; }
  double solver_prior(int) const { return 1.0; }
  int generate(int solver, const HybridSample<Translation2DEstimator>& s, Model* models) const {
    if (solver == 0) {
      models[0] = pa_[s[0][0]] - pb_[s[0][0]];
      return 1;
    }
    Eigen::Matrix2d A;
    A.row(0) = u_[s[1][0]].transpose();
    A.row(1) = u_[s[1][1]].transpose();
    if (!(std::abs(A.determinant()) > 1e-9)) return 0;
    models[0] = A.inverse() * Eigen::Vector2d(o_[s[1][0]], o_[s[1][1]]);
    return 1;
  }
  RansacScore score(const Model& t, double /*to_beat*/) const {
    RansacScore sc;
    int points = 0, projections = 0;
    for (size_t i = 0; i < pa_.size(); ++i) points += (pa_[i] - pb_[i] - t).norm() < threshold_;
    for (size_t i = 0; i < u_.size(); ++i) projections += std::abs(u_[i].dot(t) - o_[i]) < threshold_;
    sc.inliers = points + projections;
    sc.value = sc.inliers;
    sc.inlier_fraction[0] = pa_.empty() ? 0.0 : static_cast<double>(points) / pa_.size();
    sc.inlier_fraction[1] = u_.empty() ? 0.0 : static_cast<double>(projections) / u_.size();
    return sc;
  }

 private:
  const std::vector<Eigen::Vector2d>&pa_, &pb_, &u_;
  const std::vector<double>& o_;
  double threshold_;
};

}  // namespace

bool ransac_fit_line_2d(const std::vector<Eigen::Vector2d>& points, const std::vector<double>& weights,
                        double threshold, const RansacOptions& options, Eigen::Vector3d* line, RansacStats* stats) {
  Line2DEstimator estimator(points, weights, threshold);
  return ransac(estimator, options, line, stats);
}

bool ransac_translation_2d(const std::vector<Eigen::Vector2d>& points_a, const std::vector<Eigen::Vector2d>& points_b,
                           const std::vector<Eigen::Vector2d>& directions, const std::vector<double>& projections,
                           double threshold, const RansacOptions& options, Eigen::Vector2d* t, RansacStats* stats) {
  Translation2DEstimator estimator(points_a, points_b, directions, projections, threshold);
  return hybrid_ransac(estimator, options, t, stats);
}

}  // namespace line_odom
