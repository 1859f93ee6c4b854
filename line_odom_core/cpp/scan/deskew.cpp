#include "scan/deskew.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Geometry>

namespace line_odom {

namespace {

// Interpolated corrections: a sweep's times fall into this many bins between its first and last point (10 Hz sweep:
// 0.1 ms a bin, 0.1 mm at 1 m/s).
constexpr int kBins = 1024;

// When the point in `cell` was measured: time[] is indexed by the input point (source_index), or by the cell of an
// organized input.
double cell_time(const RangeImage& image, const double* time, std::size_t cell) {
  return time[image.source_index.empty() ? cell : static_cast<std::size_t>(image.source_index[cell])];
}

}  // namespace

SweepVelocity SweepVelocity::over(const RigidTransform& motion, double interval) {
  const Eigen::AngleAxisd turn(motion.R);
  SweepVelocity v;
  v.rate = turn.axis() * (turn.angle() / interval);
  v.speed = motion.t / interval;
  return v;
}

RigidTransform SweepVelocity::at(double tau) const {
  RigidTransform T;
  const double angle = rate.norm() * tau;
  if (angle != 0.0) T.R = Eigen::AngleAxisd(angle, rate.normalized()).toRotationMatrix();
  T.t = speed * tau;
  return T;
}

void deskew_image(RangeImage* image, const double* time, const SweepVelocity& velocity) {
  if (!velocity.moving()) return;
  const auto time_of = [&](std::size_t cell) { return cell_time(*image, time, cell); };
  double t0 = 0.0, t1 = 0.0;
  bool any = false;
  for (std::size_t cell = 0; cell < image->points.size(); ++cell) {
    if (!image->valid[cell]) continue;
    const double t = time_of(cell);
    t0 = any ? std::min(t0, t) : t, t1 = any ? std::max(t1, t) : t, any = true;
  }
  if (!any) return;
  const double span = t1 - t0;
  std::vector<RigidTransform> table(kBins);
  for (int b = 0; b < kBins; ++b) table[b] = velocity.at(t0 + span * b / (kBins - 1));
  for (std::size_t cell = 0; cell < image->points.size(); ++cell) {
    if (!image->valid[cell]) continue;
    const int b = span > 0.0 ? static_cast<int>(std::lround((time_of(cell) - t0) / span * (kBins - 1))) : 0;
    image->points[cell] = table[b].apply(image->points[cell]);
  }
}

void move_features(ScanFeatures* features, const SweepTimes& sweep, const SweepVelocity& target) {
  const double mid = 0.5 * (sweep.first + sweep.last);
  const auto correction = [&](double tau) { return target.at(tau) * sweep.velocity.at(tau).inverse(); };
  const auto time_at = [&](int column) {
    const bool known = column >= 0 && column < static_cast<int>(sweep.column_time.size()) &&
                       std::isfinite(sweep.column_time[static_cast<std::size_t>(column)]);
    return known ? sweep.column_time[static_cast<std::size_t>(column)] : mid;
  };
  for (LineFeature& line : features->h_lines) {  // along a row: its ends at their columns' times
    const RigidTransform Ca = correction(time_at(line.first)), Cb = correction(time_at(line.last));
    line.segment = {Ca.apply(line.segment.a), Cb.apply(line.segment.b)};
    line.line = line.segment.line();
    line.normal = Ca.R * line.normal;
  }
  for (LineFeature& line : features->v_lines) {  // along a column: one time
    const RigidTransform C = correction(time_at(line.scan_index));
    line.segment = line.segment.moved(C);
    line.line = line.line.moved(C);
    line.normal = C.R * line.normal;
  }
  const RigidTransform C = correction(mid);
  for (PlaneFeature& plane : features->planes) {
    plane.plane = plane.plane.moved(C);
    plane.centroid = C.apply(plane.centroid);
  }
}

std::vector<double> column_times(const RangeImage& image, const double* time, int step) {
  const int columns = (image.cols + step - 1) / step;
  std::vector<double> sum(static_cast<std::size_t>(columns), 0.0), count(static_cast<std::size_t>(columns), 0.0);
  for (int r = 0; r < image.rows; ++r)
    for (int c = 0; c < image.cols; c += step) {
      const std::size_t cell = static_cast<std::size_t>(r) * image.cols + c;
      if (!image.valid[cell]) continue;
      sum[static_cast<std::size_t>(c / step)] += cell_time(image, time, cell);
      count[static_cast<std::size_t>(c / step)] += 1.0;
    }
  std::vector<double> mean(static_cast<std::size_t>(columns), std::numeric_limits<double>::quiet_NaN());
  for (std::size_t c = 0; c < mean.size(); ++c)
    if (count[c] > 0.0) mean[c] = sum[c] / count[c];
  return mean;
}

double deskew_difference(const SweepVelocity& a, const SweepVelocity& b, double t0, double t1, double lever) {
  double largest = 0.0;
  for (const double tau : {t0, t1}) {
    const RigidTransform Ta = a.at(tau), Tb = b.at(tau);
    const double angle = Eigen::AngleAxisd(Ta.R.transpose() * Tb.R).angle();
    largest = std::max(largest, (Ta.t - Tb.t).norm() + angle * lever);
  }
  return largest;
}

}  // namespace line_odom
