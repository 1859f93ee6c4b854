// Which lines a scan fits and registers. A full-resolution scan has lines on every row and column, and
// neighbouring rows (columns) on one surface give nearly the same intersections; past a budget only the lines of
// every s-th row and column are fitted and registered, s the smallest step that meets it. Each kept line is still
// fitted to every point of its row or column, so it keeps its full-resolution precision, unlike lines fitted to a
// downsampled scan (paper §6.1); normals and planes come from the kept lines' crossings.
#pragma once

#include <vector>

#include "common/scan_features.hpp"
#include "features/line_fit.hpp"

namespace line_odom {

// Lines fitted on the rows and columns whose index is a multiple of fitted_step: the step s (a multiple of
// fitted_step) whose rows and columns keep at most max_lines of them, the smallest (0: no budget, fitted_step).
// When no step meets it, the step that keeps only row and column 0.
int registration_line_step(const std::vector<LineFeature>& h_lines, const std::vector<LineFeature>& v_lines,
                           int max_lines, int fitted_step = 1);

// Keeps the lines whose scan_index is a multiple of step (step 1 keeps all) and relabels the cells.
void keep_lines_every(int step, ScanLines* lines);

// The step to fit the next scan at: lines fitted on every fitted_step-th row and column stand for fitted_step times
// as many on all of them; the smallest step whose share of those is within max_lines (0: no budget, 1).
int next_fitting_step(int fitted_lines, int fitted_step, int max_lines);

}  // namespace line_odom
