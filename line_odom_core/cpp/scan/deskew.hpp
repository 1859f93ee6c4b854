// Motion compensation of a LiDAR sweep: the points a spinning sensor measured while it moved, each moved into the
// sensor frame at the scan's stamp. A point measured tau seconds after the stamp (negative: before it) is moved by
// the sensor's motion over tau at a constant velocity: turned by exp(rate tau), shifted by speed tau.
#pragma once

#include <cstddef>
#include <vector>

#include "common/scan_features.hpp"
#include "common/types.hpp"

namespace line_odom {

struct SweepVelocity {
  Vec3 rate = Vec3::Zero();    // rad/s, sensor axes
  Vec3 speed = Vec3::Zero();   // m/s, sensor axes
  bool measured_rate = false;  // the rate is this sweep's own (a gyro's over it), not the prediction's

  // The constant velocity that moves by `motion` (T_stamp_(stamp + interval)) in `interval` seconds.
  static SweepVelocity over(const RigidTransform& motion, double interval);
  bool moving() const { return !rate.isZero() || !speed.isZero(); }
  // T_stamp_(stamp + tau)
  RigidTransform at(double tau) const;
};

// What correcting a scan's features for another velocity needs.
struct SweepTimes {
  SweepVelocity velocity;           // it was deskewed at
  double first = 0.0, last = 0.0;   // its earliest and latest time
  std::vector<double> column_time;  // mean time of each column of the image its features were fitted on (NaN: none);
                                    // a spinning sensor measures a column at one time
};

// Moves each valid cell's point, measured at time[source] (s from the stamp; source = the cell's source_index, or
// the cell itself for an organized input), into the stamp's frame. The cells stay where the sweep measured them.
void deskew_image(RangeImage* image, const double* time, const SweepVelocity& velocity);

// Moves the features of a scan deskewed at sweep.velocity to where deskewing at `target` would have put them: each
// line's ends by the difference at their columns' times, planes at mid-sweep (the difference is millimetres, a rigid
// motion per column's time: fitting again gave the same errors, docs/RESULTS.md, "Deskew").
void move_features(ScanFeatures* features, const SweepTimes& sweep, const SweepVelocity& target);

// Mean time of every `step`-th column of `image` (the columns of downsample(image, step)), NaN where it has no point;
// time indexed as for deskew_image.
std::vector<double> column_times(const RangeImage& image, const double* time, int step);

// The largest distance between where the two velocities put a point `lever` metres from the sensor measured at t0 or
// t1 (the ends of a sweep): how differently two scans corrected with them are deskewed.
double deskew_difference(const SweepVelocity& a, const SweepVelocity& b, double t0, double t1, double lever);

}  // namespace line_odom
