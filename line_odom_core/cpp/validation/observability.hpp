// Whether the line pairs pin a motion down (beyond the paper). An H-line and a V-line on one plane meet under any
// motion within that plane, so on a street of walls and ground most pairs meet under the estimate and under the
// estimate pushed along the street alike: their count says nothing about that direction. A direction is observed
// when the pairs that meet under the estimate only significantly outweigh those that meet under the pushed motion
// only (McNemar's test on the discordant pairs, each counted with its inlier weight).
#pragma once

#include "common/types.hpp"
#include "registration/correspondences.hpp"
#include "registration/line_pair_table.hpp"

namespace line_odom {

struct ObservabilityOptions {
  bool enabled = true;
  double tolerance = 0.3;       // m: a registered motion is claimed right to this along every direction
  double motion_share = 0.3;    // ... or to this share of its own translation, when that is larger
  double significance = 3.0;    // z: a push the pairs reject less significantly leaves its direction unobserved
};

struct Observability {
  Vec6 z = Vec6::Zero();  // per direction of xi (x y z rx ry rz): the smaller z of its two pushes
  double push = 0.0;      // m: how far each push moved the lines (translations; rotations at `lever`)
  double lever = 1.0;     // m: the inlier lines' rms distance from the sensor
  int unobserved = 0;     // bit k: direction k's z below the significance
};

// The pairs meeting under T (within `threshold`, sines >= min_sine) against those meeting under T pushed by
// `push` metres (a translation) or push / lever radians (a rotation) either way along each axis of xi.
Observability test_observability(const Correspondences& corr, const LinePairTable& pairs, const RigidTransform& T, double threshold,
                                 double min_sine, double push, double significance);

// The push that tests a motion: options.tolerance, or options.motion_share of its translation when larger.
double observability_push(const RigidTransform& motion, const ObservabilityOptions& options);

}  // namespace line_odom
