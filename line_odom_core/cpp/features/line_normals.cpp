#include "features/line_normals.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "common/lent_workspace.hpp"
#include "common/simd.hpp"

namespace line_odom {

namespace {

constexpr double kDeg = kPi / 180.0;

// The crossings of each line, packed contiguously in ascending crossing order (the robust mean reads them
// three times).
struct PackedCrossing {
  Vec3 normal;
  double weight;
};
struct CrossingLists {
  std::vector<int> offset;  // size lines + 1
  std::vector<PackedCrossing> items;
};

// Work buffers of the normals, kept per thread (lent_workspace.hpp).
struct NormalWorkspace {
  CrossingLists lists;
  std::vector<int> fill;
  std::vector<LineFeature*> members;
  std::vector<Vec3> normals, own;
  std::vector<std::int8_t> cluster;
  std::vector<int> votes, near;
  std::vector<double> vx, vy, vz;
};

const CrossingLists& build_lists(const std::vector<LineCrossing>& crossings, size_t lines, bool horizontal,
                                 NormalWorkspace& ws) {
  CrossingLists& l = ws.lists;
  l.offset.assign(lines + 1, 0);
  for (const auto& x : crossings) ++l.offset[(horizontal ? x.h : x.v) + 1];
  for (size_t i = 0; i < lines; ++i) l.offset[i + 1] += l.offset[i];
  l.items.resize(crossings.size());
  ws.fill.assign(l.offset.begin(), l.offset.end() - 1);
  int* fill = ws.fill.data();
  for (const auto& x : crossings) l.items[fill[horizontal ? x.h : x.v]++] = {x.normal, x.weight};
  return l;
}

void robust_normal(const CrossingLists& lists, const NormalConfig& cfg, std::vector<LineFeature>* lines) {
  const double cos_wide = std::cos(std::min(90.0, 2.0 * cfg.max_deviation_deg) * kDeg);
  const double cos_dev = std::cos(cfg.max_deviation_deg * kDeg);
  const PackedCrossing* items = lists.items.data();
  for (size_t i = 0; i < lines->size(); ++i) {
    LineFeature& f = (*lines)[i];
    f.normal.setZero();
    f.normal_support = 0;
    const int b = lists.offset[i], e = lists.offset[i + 1];
    if (e == b) continue;
    Vec3 sum = Vec3::Zero();
    double total = 0.0;
    for (int k = b; k < e; ++k) {
      const PackedCrossing& x = items[k];
      sum += x.weight * x.normal;
      total += x.weight;
    }
    // v.normalized() is v / v.norm() for v != 0 (the same square root and divisions).
    const double sum_norm = sum.norm();
    if (sum_norm < 1e-9) continue;
    const Vec3 sum_mean = sum / sum_norm;
    // When every crossing agrees, the sums over the agreeing ones are the first pass's sums (same terms, same
    // order), and so is the new mean: only the test is needed. Both passes test against sum_mean while that
    // holds, so the dot products are taken once for both limits (cos_dev >= cos_wide).
    bool all_wide = true, all_dev = true;
    for (int k = b; k < e; ++k) {
      const double d = items[k].normal.dot(sum_mean);
      all_wide &= d >= cos_wide;
      all_dev &= d >= cos_dev;
    }
    Vec3 mean = sum_mean;
    bool mean_is_sum = true;
    int agree = 0;
    double agree_weight = 0.0;
    for (int pass = 0; pass < 2; ++pass) {
      const double cos_limit = pass == 0 ? cos_wide : cos_dev;
      bool all = pass == 0 ? all_wide : all_dev;
      if (!mean_is_sum) {
        all = true;
        for (int k = b; k < e && all; ++k) all = items[k].normal.dot(mean) >= cos_limit;
      }
      if (all) {
        agree = e - b;
        agree_weight = total;
        mean = sum_mean;
        continue;
      }
      mean_is_sum = false;
      Vec3 next = Vec3::Zero();
      agree = 0;
      agree_weight = 0.0;
      for (int k = b; k < e; ++k) {
        const PackedCrossing& x = items[k];
        if (x.normal.dot(mean) >= cos_limit) {
          next += x.weight * x.normal;
          agree_weight += x.weight;
          ++agree;
        }
      }
      const double next_norm = next.norm();
      if (agree == 0 || next_norm < 1e-9) break;
      mean = next / next_norm;
    }
    if (agree < cfg.min_crossings || agree_weight < cfg.min_agreement * total) continue;
    f.normal = mean;
    f.normal_support = agree;
  }
}

// Cells where both labels are >= 0 (then so is their bitwise or), of n.
LINE_ODOM_VECTOR_CLONES int count_both_labelled(const std::int32_t* h_label, const std::int32_t* v_label, int n) {
  int both = 0;
  for (int k = 0; k < n; ++k) both += (h_label[k] | v_label[k]) >= 0;
  return both;
}

// Voters (structure of arrays) within the vote cone of c, sign-folded.
LINE_ODOM_VECTOR_CLONES int count_votes(const double* vx, const double* vy, const double* vz, int voters,
                                        double cx, double cy, double cz, double cos_vote) {
  int votes = 0;
  for (int j = 0; j < voters; ++j) votes += std::abs(vx[j] * cx + vy[j] * cy + vz[j] * cz) >= cos_vote;
  return votes;
}

// Principal axis of the normals within cos_limit of `axis` (sign-folded); `axis` itself when none. `near` is a
// work buffer: the indices of those normals are listed first without branches (the test mispredicts), then summed.
Vec3 refine_axis(const std::vector<Vec3>& normals, const Vec3& axis, double cos_limit, std::vector<int>& near) {
  near.resize(normals.size());
  int n = 0;
  for (size_t i = 0; i < normals.size(); ++i) {
    near[n] = static_cast<int>(i);
    n += std::abs(normals[i].dot(axis)) >= cos_limit;
  }
  // The 6 distinct entries of sum v v^T (the full sum is symmetric bit for bit: v_i v_j == v_j v_i).
  double xx = 0.0, xy = 0.0, xz = 0.0, yy = 0.0, yz = 0.0, zz = 0.0;
  for (int k = 0; k < n; ++k) {
    const Vec3& v = normals[near[k]];
    const double x = v.x(), y = v.y(), z = v.z();
    xx += x * x, xy += x * y, xz += x * z, yy += y * y, yz += y * z, zz += z * z;
  }
  if (n == 0) return axis;
  Mat3 scatter;
  scatter << xx, xy, xz, xy, yy, yz, xz, yz, zz;
  Eigen::SelfAdjointEigenSolver<Mat3> eig;
  eig.computeDirect(scatter);
  Vec3 out = eig.eigenvectors().col(2).normalized();
  return out.dot(axis) < 0.0 ? Vec3(-out) : out;
}

// Deterministic sign: the largest component positive.
Vec3 canonical_sign(const Vec3& v) {
  int k = 0;
  v.cwiseAbs().maxCoeff(&k);
  return v(k) < 0.0 ? Vec3(-v) : v;
}

}  // namespace

std::vector<LineCrossing> find_crossings(const RangeImage& image, const ScanLines& lines,
                                         const NormalConfig& config) {
  const double sin_min = std::sin(config.min_crossing_angle_deg * kDeg);
  const std::int32_t* h_label = lines.h_label.data();
  const std::int32_t* v_label = lines.v_label.data();
  // Cells held by both lines, counted per row: rows without any (most rows of a sparsely fitted scan hold no
  // H-line) are passed over.
  std::vector<int> row_both(image.rows);
  int both = 0;
  for (int r = 0; r < image.rows; ++r) {
    row_both[r] = count_both_labelled(h_label + r * image.cols, v_label + r * image.cols, image.cols);
    both += row_both[r];
  }
  std::vector<LineCrossing> out;
  out.reserve(both);
  // The V-line fields a crossing reads, packed: the cells of a row visit V-lines in scattered order.
  struct VLineSpan {
    int first, last;
    Vec3 d;
  };
  std::vector<VLineSpan> v_spans(lines.v_lines.size());
  for (size_t i = 0; i < v_spans.size(); ++i) {
    const LineFeature& f = lines.v_lines[i];
    v_spans[i] = {f.first, f.last, f.line.d};
  }
  for (int r = 0; r < image.rows; ++r) {
    if (row_both[r] == 0) continue;
    for (int c = 0, cell = r * image.cols; c < image.cols; ++c, ++cell) {
      const int h = h_label[cell], v = v_label[cell];
      if (h < 0 || v < 0) continue;
      // A true crossing has points of both lines on both sides; a shared end point may be a corner where a line
      // of one surface meets a line of another (their cross product is neither's normal): it weighs less.
      const LineFeature& lh = lines.h_lines[h];
      const VLineSpan& lv = v_spans[v];
      const bool at_end = c == lh.first || c == lh.last || r == lv.first || r == lv.last;
      Vec3 n = lh.line.d.cross(lv.d);
      const double s = n.norm();
      if (s < sin_min) continue;
      n /= s;
      if (n.dot(image.points[cell]) > 0.0) n = -n;
      out.push_back({h, v, cell, n, at_end ? config.end_crossing_weight : 1.0});
    }
  }
  return out;
}

void assign_line_normals(const std::vector<LineCrossing>& crossings, const NormalConfig& config,
                         ScanLines* lines) {
  LentWorkspace<NormalWorkspace> lent;
  NormalWorkspace& ws = *lent;
  robust_normal(build_lists(crossings, lines->h_lines.size(), true, ws), config, &lines->h_lines);
  robust_normal(build_lists(crossings, lines->v_lines.size(), false, ws), config, &lines->v_lines);
}

std::array<Vec3, 3> cluster_line_normals(const NormalConfig& config, std::vector<LineFeature>* h_lines,
                                         std::vector<LineFeature>* v_lines) {
  LentWorkspace<NormalWorkspace> lent;
  NormalWorkspace& ws = *lent;
  auto& members = ws.members;
  auto& normals = ws.normals;
  members.clear();
  normals.clear();
  for (auto* list : {h_lines, v_lines})
    for (auto& f : *list) {
      f.cluster = -1;
      if (f.normal.squaredNorm() > 0.25) {
        members.push_back(&f);
        normals.push_back(f.normal.normalized());
      }
    }
  std::array<Vec3, 3> dirs{Vec3::UnitX(), Vec3::UnitY(), Vec3::UnitZ()};
  const size_t n = normals.size();
  if (n == 0) return dirs;

  const double cos_vote = std::cos(config.vote_angle_deg * kDeg);
  const double cos_sep = std::cos(config.min_separation_deg * kDeg);
  const size_t cand_stride = std::max<size_t>(1, n / 96);
  const size_t vote_stride = std::max<size_t>(1, n / 2000);
  auto separated = [&](const Vec3& c, int found) {
    for (int k = 0; k < found; ++k)
      if (std::abs(c.dot(dirs[k])) > cos_sep) return false;
    return true;
  };
  // The voters as structure of arrays: the vote count below is a vectorizable loop (same products and sums).
  auto& vx = ws.vx;
  auto& vy = ws.vy;
  auto& vz = ws.vz;
  vx.clear();
  vy.clear();
  vz.clear();
  for (size_t j = 0; j < n; j += vote_stride) {
    vx.push_back(normals[j].x());
    vy.push_back(normals[j].y());
    vz.push_back(normals[j].z());
  }
  const int voter_count = static_cast<int>(vx.size());
  // A candidate's votes do not depend on the round: counted once, when first needed.
  auto& votes_of = ws.votes;
  votes_of.assign((n + cand_stride - 1) / cand_stride, -1);
  int found = 0;
  for (; found < 3; ++found) {
    int best_votes = 0;
    Vec3 best = Vec3::Zero();
    for (size_t i = 0; i < n; i += cand_stride) {
      const Vec3& c = normals[i];
      if (!separated(c, found)) continue;
      int& votes = votes_of[i / cand_stride];
      if (votes < 0) votes = count_votes(vx.data(), vy.data(), vz.data(), voter_count, c.x(), c.y(), c.z(), cos_vote);
      if (votes > best_votes) {
        best_votes = votes;
        best = c;
      }
    }
    const double voters = static_cast<double>((n + vote_stride - 1) / vote_stride);
    if (best_votes == 0 || best_votes < config.min_cluster_fraction * voters) break;
    for (int it = 0; it < 3; ++it) best = refine_axis(normals, best, cos_vote, ws.near);
    if (!separated(best, found)) break;
    dirs[found] = best;
  }
  if (found == 0) return dirs;
  if (found == 1) {
    // Any direction perpendicular to the first: the axis least aligned with it, orthogonalized.
    int k = 0;
    dirs[0].cwiseAbs().minCoeff(&k);
    dirs[1] = dirs[0].cross(Vec3::Unit(k)).normalized();
  }
  if (found <= 2) dirs[2] = dirs[0].cross(dirs[1]).normalized();

  const double cos_member = std::cos(config.max_cluster_angle_deg * kDeg);
  // Each member's cluster, also kept here: the refinement below reads it without visiting the lines.
  auto& cluster = ws.cluster;
  cluster.resize(n);
  auto assign = [&]() {
    for (size_t i = 0; i < n; ++i) {
      int best = -1;
      double best_cos = cos_member - 1e-12;
      for (int k = 0; k < 3; ++k) {
        const double c = std::abs(normals[i].dot(dirs[k]));
        if (c >= best_cos) {
          best_cos = c;
          best = k;
        }
      }
      members[i]->cluster = best;
      cluster[i] = static_cast<std::int8_t>(best);
    }
  };
  assign();
  // Refine each direction on its own members near it, then reassign.
  const double cos_refine = std::cos(std::min(89.0, 2.0 * config.vote_angle_deg) * kDeg);
  for (int k = 0; k < found; ++k) {
    auto& own = ws.own;
    own.clear();
    for (size_t i = 0; i < n; ++i)
      if (cluster[i] == k) own.push_back(normals[i]);
    dirs[k] = refine_axis(own, dirs[k], cos_refine, ws.near);
  }
  for (auto& d : dirs) d = canonical_sign(d);
  assign();
  return dirs;
}

}  // namespace line_odom
