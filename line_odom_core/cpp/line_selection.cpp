#include "line_selection.hpp"

#include <algorithm>
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

}  // namespace

int registration_line_step(const ScanFeatures& features, int max_lines) {
  const auto total = features.h_lines.size() + features.v_lines.size();
  if (max_lines <= 0 || total <= static_cast<size_t>(max_lines)) return 1;
  // Past the largest index only row and column 0 remain: no larger step keeps fewer lines.
  const int last = std::max(largest_scan_index(features.h_lines), largest_scan_index(features.v_lines)) + 1;
  int step = 2;
  for (; step < last; ++step)
    if (lines_kept(features.h_lines, step) + lines_kept(features.v_lines, step) <= max_lines) break;
  return step;
}

void keep_lines_every(int step, ScanFeatures* features) {
  if (step <= 1) return;
  for (std::vector<LineFeature>* lines : {&features->h_lines, &features->v_lines})
    lines->erase(std::remove_if(lines->begin(), lines->end(),
                                [step](const LineFeature& l) { return l.scan_index % step != 0; }),
                 lines->end());
}

}  // namespace line_odom
