// Which fitted lines enter the registration. A full-resolution scan yields lines on every row and column, and
// neighbouring rows (columns) on one surface give nearly the same intersections; past a budget only the lines of
// every s-th row and column are registered, s the smallest step that meets it. The lines are still fitted, and
// normals and planes found, on every row and column (paper §6.2): the kept lines keep their full-resolution
// precision, unlike lines fitted to a downsampled scan (§6.1).
#pragma once

#include "scan_features.hpp"

namespace line_odom {

// The smallest step s >= 1 for which the H-lines of rows and the V-lines of columns whose index is a multiple of
// s number at most max_lines (0: no budget, step 1). When no step meets it, the step that keeps only row and
// column 0.
int registration_line_step(const ScanFeatures& features, int max_lines);

// Keeps the lines whose scan_index is a multiple of step (step 1 keeps all).
void keep_lines_every(int step, ScanFeatures* features);

}  // namespace line_odom
