// What one registered frame returns: the pose, the motion since the previous frame with its covariance, and the
// statistics of how it was found.
#pragma once

#include <string>

#include "common/types.hpp"

namespace line_odom {

// Where a frame's motion came from.
enum class Solver {
  kNone,          // the first frame: nothing to register against
  k7L,            // paper §4
  k3L1P,          // paper §5.2
  k1L2P,          // paper §5.1
  kRefinedGuess,  // the start (prediction or search) refined on the candidates out-supported every sample
  kPoints,        // the lines registered nothing: the scan's points aligned to the local map (point_alignment.hpp)
  kPrediction,    // nothing registered: the prediction held
};

const char* solver_name(Solver solver);
// The solver a RANSAC statistic names (MotionStats::best_solver: 0 7L, 1 3L1P, 2 1L2P, -2 the incumbent).
Solver solver_from_ransac(int best_solver);

struct StageMilliseconds {
  double organize = 0, downsample = 0, features = 0, candidates = 0, ransac = 0, total = 0;
  double lines = 0, normals = 0, planes = 0;  // parts of features
  double points = 0;  // the point-to-plane refinement, its surface built for the next frame included
  double validation = 0;  // the lines' observability, the points' alignment and their map
  double deskew = 0;  // correcting both scans' sweeps (before the registration: part of organize; after it, at the
                      // registered motion: besides the stages)
};

struct FrameStats {
  Solver solver = Solver::kNone;
  int points = 0;               // valid points after downsampling
  int h_lines = 0, v_lines = 0, planes = 0;
  int fit_step = 1;             // h_lines, v_lines fitted on every fit_step-th row and column (line_selection.hpp)
  int line_step = 1;            // of them, those of every line_step-th row and column kept (registration.max_lines)
  int registered_lines = 0;     // of h_lines + v_lines
  int candidates = 0, plane_candidates = 0;  // of the last pass
  int inliers = 0, plane_inliers = 0;
  double inlier_weight = 0.0;
  double residual_rms = 0.0;
  int iterations = 0;           // RANSAC hypotheses over all passes
  int passes = 0;               // passes that produced an estimate
  bool registered = false;      // an estimate was accepted for this frame
  bool degenerate = false;      // registration failed or was ill-conditioned: the prediction was held (in full, or
                                // along held_directions)
  int held_directions = 0;      // 1..5: a partial estimate, these directions from the prediction; 6: held in full
  Vec6 persistence = Vec6::Ones();  // share of the last motion predicted for this frame, per axis (x y z rx ry rz)
  std::string prediction = "none";  // where the prediction came from: "constant_velocity", "guess" (the caller's),
                                    // "standing_still" (no velocity yet, or registration.constant_velocity off);
                                    // "+imu" appended when its rotation is the caller's rotation_guess
  std::string failure;          // why, when degenerate
  int unmeasured_directions = 0;  // of the velocity, never measured since the first motion was held (at standing
                                  // still): searched on the next frames
  bool recovered = false;       // this frame's motion was found by that search
  bool turn_searched = false;   // the registration failed, held a rotation or kept under a third of the last frame's
                                // inlier weight: the heading was scanned (search_turn)
  bool turn_recovered = false;  // ... and the motion registered from the best-supported heading replaced it
  int window_scans = 0;         // previous scans the motion was registered against (registration.window; 0: none)
  bool deskewed = false;        // the points had times and were moved to the stamp at the predicted velocity
  bool previous_deskewed_again = false;  // ... and the previous scan, deskewed at another velocity, was again at this
                                         // one (its features moved), so that both scans are corrected alike
  int deskewed_again = 0;  // times the sweep was deskewed again at the motion registered for it, and registered again
                           // (sensor.deskew_iterations)
  bool points_refined = false;  // the point-to-plane refinement (points.weight) moved the lines' estimate
  int point_matches = 0;        // ... with this many of the scan's voxel means on a planar voxel of the previous scan
  // validation.*: McNemar's z per direction (x y z rx ry rz) of the lines' pairs at the motion against the motion
  // pushed either way (observability.hpp); 0 where not tested
  Vec6 observability = Vec6::Zero();
  int unobserved = 0;           // bit k: direction k not pinned down by the lines (z under validation.significance)
  bool points_aligned = false;  // the scan's points were aligned to the local map (point_map.*)
  int point_map_matches = 0;    // ... this many of them with a map point within the alignment's threshold
  std::string map_entry = "none";  // where the scan entered the local map: "pose" (its registered pose), "points"
                                   // (partly held at the prediction: where its points put it), "none" (stayed out: the
                                   // map does not judge the next frame)
  StageMilliseconds ms;
};

struct FrameResult {
  double stamp = 0.0;
  RigidTransform pose;   // T_world_sensor
  RigidTransform delta;  // T_prev_curr
  Mat6 covariance = Mat6::Zero();  // of delta, order (x y z rx ry rz)
  FrameStats stats;
};

}  // namespace line_odom
