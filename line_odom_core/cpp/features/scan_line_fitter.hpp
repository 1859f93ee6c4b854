// The lines of single scan lines, by split-and-merge (line_fit.hpp describes the steps): the work of fit_scan_lines
// on one block of rows or columns.
#pragma once

#include <cstdint>
#include <vector>

#include "common/scan_features.hpp"
#include "features/line_fit.hpp"
#include "features/scan_line_buffer.hpp"

namespace line_odom::line_fit_detail {

// Fits rows (horizontal) or columns [begin, end), every scan_step-th one, appending their lines to `lines` and
// labelling their cells in `labels` (indices into `lines`). Uses the calling thread's work buffers, kept at their
// largest size: a full frame needs a few MB, which the allocator would otherwise map and the kernel fault in and zero
// again on every call.
void fit_scan_block(const RangeImage& image, const LineFitConfig& config, const CellThresholds& thresholds,
                    bool horizontal, int scan_step, int begin, int end, std::vector<LineFeature>* lines,
                    std::vector<std::int32_t>* labels);

}  // namespace line_odom::line_fit_detail
