// Surface normals of lines from H/V line crossings in the same scan, and their clustering into 3 directions
// (paper §6.2 "Line Fitting" and §6.3 "Candidate Selection").
//
// An H-line and a V-line that hold the same range-image cell cross there; both lie
// on the surface, so the surface normal at the crossing is the cross product of their directions (oriented
// towards the sensor). Crossings at a line's end weigh less: that is where lines of two surfaces meet at corners.
// Each line takes the robust mean of its crossings' normals (mean, then re-mean over the crossings within
// max_deviation_deg, twice). Clustering is dominant-direction voting on the sphere with sign folding: the
// direction with the most line normals within vote_angle_deg, then the most voted direction at least
// min_separation_deg from the ones found (the third falls back to the cross product of the first two), each
// refined by the principal axis of its members; every line joins the nearest direction.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "common/scan_features.hpp"
#include "features/line_fit.hpp"

namespace line_odom {

struct NormalConfig {
  double min_crossing_angle_deg = 25.0;  // normals.min_crossing_angle_deg: flatter crossings give no normal
  double max_deviation_deg = 15.0;       // normals.max_deviation_deg: crossings off the line's mean are outliers
  int min_crossings = 1;                 // normals.min_crossings: agreeing crossings a line needs
  double min_agreement = 0.5;            // normals.min_agreement: fraction of its crossings that must agree
  double vote_angle_deg = 10.0;          // normals.vote_angle_deg: radius of a direction vote
  double min_separation_deg = 45.0;      // normals.min_separation_deg: between cluster directions
  double max_cluster_angle_deg = 90.0;   // normals.max_cluster_angle_deg: farther normals stay unclustered
  double min_cluster_fraction = 0.02;    // normals.min_cluster_fraction: votes a direction needs (of all normals)
  double end_crossing_weight = 0.25;     // normals.end_crossing_weight: weight of crossings at a line's end
};

// A crossing of H-line h and V-line v at a cell, with the unit normal there (towards the sensor).
struct LineCrossing {
  std::int32_t h = -1;
  std::int32_t v = -1;
  std::int32_t cell = -1;
  Vec3 normal = Vec3::Zero();
  double weight = 1.0;  // end_crossing_weight at a line's end, else 1
};

// Finds the crossings (cells held by both an H- and a V-line, crossing angle large enough).
std::vector<LineCrossing> find_crossings(const RangeImage& image, const ScanLines& lines,
                                         const NormalConfig& config);

// Sets LineFeature::normal and normal_support of every line from the crossings (0 / 0 when unknown).
void assign_line_normals(const std::vector<LineCrossing>& crossings, const NormalConfig& config,
                         ScanLines* lines);

// Clusters the known line normals into 3 directions: sets LineFeature::cluster and returns the directions.
std::array<Vec3, 3> cluster_line_normals(const NormalConfig& config, std::vector<LineFeature>* h_lines,
                                         std::vector<LineFeature>* v_lines);

}  // namespace line_odom
