#include "features/line_fit.hpp"

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <utility>
#include <vector>

#include "common/worker_pool.hpp"
#include "features/scan_line_buffer.hpp"
#include "features/scan_line_fitter.hpp"

namespace line_odom {

namespace {

using line_fit_detail::CellThresholds;

// Rows (horizontal) or columns [begin, end), every scan_step-th one; begin is a multiple of scan_step.
struct ScanBlock {
  bool horizontal = true;
  int begin = 0, end = 0;
  bool first = true;                   // the pass's first block writes the frame's list itself; the others ...
  std::vector<LineFeature> own_lines;  // ... their own, labelled from 0 in their cells
  size_t offset = 0;                   // of own_lines[0] in the frame's list
};


void fit_block(const RangeImage& image, const LineFitConfig& config, const CellThresholds& thresholds, int scan_step,
               ScanBlock* block, std::vector<LineFeature>* frame_lines, std::vector<std::int32_t>* labels) {
  std::vector<LineFeature>* lines = block->first ? frame_lines : &block->own_lines;
  line_fit_detail::fit_scan_block(image, config, thresholds, block->horizontal, scan_step, block->begin, block->end,
                                  lines, labels);
}

// A pass split into `parts` blocks of whole scans, aligned to scan_step.
void add_blocks(bool horizontal, int scans, int scan_step, int parts, std::vector<ScanBlock>* blocks) {
  const int fitted = (scans + scan_step - 1) / scan_step;
  parts = std::max(1, std::min(parts, fitted));
  for (int p = 0; p < parts; ++p) {
    ScanBlock b;
    b.horizontal = horizontal;
    b.begin = static_cast<int>(static_cast<long long>(fitted) * p / parts) * scan_step;
    b.end = std::min(scans, static_cast<int>(static_cast<long long>(fitted) * (p + 1) / parts) * scan_step);
    b.first = p == 0;
    blocks->push_back(std::move(b));
  }
}

// Copies a later block's lines into the frame's list (sized already) at its offset and shifts its cells' labels.
void gather_block(const RangeImage& image, const ScanBlock& block, std::vector<LineFeature>* frame_lines,
                  std::vector<std::int32_t>* labels) {
  if (block.first) return;
  std::copy(block.own_lines.begin(), block.own_lines.end(), frame_lines->begin() + block.offset);
  if (block.offset == 0 || block.own_lines.empty()) return;
  const auto shift = static_cast<std::int32_t>(block.offset);
  std::int32_t* cells = labels->data();
  for (int r = block.horizontal ? block.begin : 0; r < (block.horizontal ? block.end : image.rows); ++r) {
    std::int32_t* row = cells + static_cast<std::ptrdiff_t>(r) * image.cols;
    const int c0 = block.horizontal ? 0 : block.begin, c1 = block.horizontal ? image.cols : block.end;
    for (int c = c0; c < c1; ++c)
      if (row[c] >= 0) row[c] += shift;
  }
}

}  // namespace

ScanLines fit_scan_lines(const RangeImage& image, const LineFitConfig& config, int scan_step, WorkerPool* pool) {
  if (scan_step < 1) throw std::invalid_argument("scan_step: expected >= 1");
  const size_t cells = static_cast<size_t>(image.rows) * image.cols;
  if (image.rows < 0 || image.cols < 0 || image.points.size() != cells || image.valid.size() != cells)
    throw std::invalid_argument("range image: points/valid sizes do not match rows x cols");
  ScanLines out;
  // the line lists grow to about the sizes of this thread's previous call (no reallocation copies)
  thread_local size_t previous_h = 0, previous_v = 0;
  out.h_lines.reserve(previous_h + previous_h / 8);
  out.v_lines.reserve(previous_v + previous_v / 8);
  out.h_label.assign(cells, -1);
  out.v_label.assign(cells, -1);
  thread_local CellThresholds kept_thresholds;
  line_fit_detail::cell_thresholds(image, config, kept_thresholds);
  const CellThresholds& thresholds = kept_thresholds;  // the caller's, read by every block (a lambda naming a
                                                       // thread_local would read its own thread's)
  // Blocks: with workers, each pass in about twice as many blocks as threads (the row pass carries ~40 % of the
  // work), taken in order; alone, or for an image too small to repay waking the workers, one block per pass.
  constexpr size_t kMinSharedPoints = 1 << 15;  // ~0.5 ms of fitting (a full KITTI frame: 262k, every 4th: 66k)
  const size_t fitted_points = static_cast<size_t>((image.rows + scan_step - 1) / scan_step) * image.cols +
                               static_cast<size_t>((image.cols + scan_step - 1) / scan_step) * image.rows;
  const bool shared = has_workers(pool) && fitted_points >= kMinSharedPoints;
  const int parts = shared ? 2 * pool->threads() : 1;
  std::vector<ScanBlock> blocks;
  add_blocks(true, image.rows, scan_step, parts, &blocks);
  add_blocks(false, image.cols, scan_step, parts, &blocks);
  auto lines_of = [&](const ScanBlock& b) { return b.horizontal ? &out.h_lines : &out.v_lines; };
  auto labels_of = [&](const ScanBlock& b) { return b.horizontal ? &out.h_label : &out.v_label; };
  auto fit = [&](int b) { fit_block(image, config, thresholds, scan_step, &blocks[b], lines_of(blocks[b]),
                                    labels_of(blocks[b])); };
  if (parts == 1) {
    for (int b = 0; b < static_cast<int>(blocks.size()); ++b) fit(b);
  } else {
    pool->run(static_cast<int>(blocks.size()), fit);
    for (auto* list : {&out.h_lines, &out.v_lines}) {
      size_t size = list->size();
      for (auto& b : blocks)
        if (!b.first && lines_of(b) == list) {
          b.offset = size;
          size += b.own_lines.size();
        }
      list->resize(size);
    }
    pool->run(static_cast<int>(blocks.size()),
              [&](int b) { gather_block(image, blocks[b], lines_of(blocks[b]), labels_of(blocks[b])); });
  }
  previous_h = out.h_lines.size();
  previous_v = out.v_lines.size();
  return out;
}

}  // namespace line_odom
