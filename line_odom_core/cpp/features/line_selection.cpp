#include "features/line_selection.hpp"

#include <algorithm>
#include <cstdint>
#include <vector>

namespace line_odom {

namespace {

int lines_kept(const std::vector<LineFeature>& lines, int step) {
  return static_cast<int>(
      std::count_if(lines.begin(), lines.end(), [step](const LineFeature& l) { return l.scan_index % step == 0; }));
}

int largest_scan_index(const std::vector<LineFeature>& lines) {
  int largest = 0;
  for (const LineFeature& l : lines) largest = std::max(largest, l.scan_index);
  return largest;
}

// Keeps the lines of scans that are multiples of step; labels[cell] (an index into lines or -1) follows.
void keep_every(int step, std::vector<LineFeature>* lines, std::vector<std::int32_t>* labels) {
  std::vector<std::int32_t> new_index(lines->size(), -1);
  std::size_t kept = 0;
  for (std::size_t i = 0; i < lines->size(); ++i) {
    if ((*lines)[i].scan_index % step != 0) continue;
    new_index[i] = static_cast<std::int32_t>(kept);
    (*lines)[kept++] = (*lines)[i];
  }
  if (kept == lines->size()) return;  // nothing dropped: the labels stand
  lines->resize(kept);
  for (std::int32_t& label : *labels)
    if (label >= 0) label = new_index[static_cast<std::size_t>(label)];
}

}  // namespace

int registration_line_step(const std::vector<LineFeature>& h_lines, const std::vector<LineFeature>& v_lines,
                           int max_lines, int fitted_step) {
  const int base = std::max(1, fitted_step);
  const auto total = h_lines.size() + v_lines.size();
  if (max_lines <= 0 || total <= static_cast<std::size_t>(max_lines)) return base;
  // Past the largest index only row and column 0 remain: no larger step keeps fewer lines.
  const int last = std::max(largest_scan_index(h_lines), largest_scan_index(v_lines)) + 1;
  int step = 2 * base;
  for (; step < last; step += base)
    if (lines_kept(h_lines, step) + lines_kept(v_lines, step) <= max_lines) break;
  return step;
}

void keep_lines_every(int step, ScanLines* lines) {
  if (step <= 1) return;
  keep_every(step, &lines->h_lines, &lines->h_label);
  keep_every(step, &lines->v_lines, &lines->v_label);
}

int next_fitting_step(int fitted_lines, int fitted_step, int max_lines) {
  if (max_lines <= 0) return 1;
  const long long all_lines = static_cast<long long>(fitted_lines) * std::max(1, fitted_step);
  return static_cast<int>(std::max<long long>(1, (all_lines + max_lines - 1) / max_lines));
}

}  // namespace line_odom
