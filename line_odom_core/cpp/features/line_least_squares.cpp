#include "features/line_least_squares.hpp"

namespace line_odom {

Mat3 PointMoments::covariance() const {
  if (count == 0) return Mat3::Zero();
  const Vec3 c = mean();
  return outer / count - c * c.transpose();
}

LineLeastSquares fit_line(const PointMoments& moments, const Vec3& seed, int iterations) {
  const Mat3& o = moments.outer;
  return line_fit_detail::fit_upper(moments.count, moments.sum, o(0, 0), o(0, 1), o(0, 2), o(1, 1), o(1, 2),
                                    o(2, 2), seed, iterations);
}

LineLeastSquares fit_line(const PointMoments& moments) {
  const Mat3 C = moments.covariance();
  int k = 0;
  C.diagonal().maxCoeff(&k);
  return fit_line(moments, C.col(k), 6);
}

namespace line_fit_detail {

__attribute__((noinline, cold)) LineLeastSquares refit_from_axis(int count, const Vec3& sum, double oxx, double oxy,
                                                                 double oxz, double oyy, double oyz, double ozz,
                                                                 int axis, int iterations) {
  return fit_upper(count, sum, oxx, oxy, oxz, oyy, oyz, ozz, Vec3::Unit(axis), iterations);
}

}  // namespace line_fit_detail

}  // namespace line_odom
