// The lines and planes of the last few scans, moved into the newest one's frame by the estimated motions, so a scan
// can be registered against more than one predecessor (registration.window; 1 = the paper's frame-to-frame §6.3).
#pragma once

#include <cstddef>
#include <deque>

#include "common/scan_features.hpp"
#include "common/types.hpp"

namespace line_odom {

class FeatureWindow {
 public:
  explicit FeatureWindow(int scans = 1) : scans_(scans < 1 ? 1 : scans) {}

  // The next scan's features; delta = T_newest_next, the estimated motion from the newest scan to it. Unless
  // `measured` (registered in full: nothing held at the prediction), the older scans are dropped: their place
  // relative to the next one would come from the prediction, not from the scans.
  void push(const ScanFeatures& next, const RigidTransform& delta, bool measured);
  // The newest scan's features moved by a correction of its own (deskewed again at another velocity); its place stays.
  void replace_newest(const ScanFeatures& features) {
    if (!entries_.empty()) entries_.front().features = features;
  }
  void clear() { entries_.clear(); }
  std::size_t size() const { return entries_.size(); }

  // How many of the scans, newest first, a registration takes: older ones while the lines taken number fewer than
  // `max_lines` (registration.max_lines; 0: no bound). Older scans add lines where the newest has few; a scan with as
  // many lines as one registration is given registers on its own (the paper's frame-to-frame registration).
  std::size_t scans_within(int max_lines) const;
  // The newest scan's features followed by the next `scans` - 1 older scans' lines and planes, in the newest scan's
  // frame; an older line's normal cluster is the newest scan's cluster direction nearest to its normal (-1 beyond
  // 45 deg).
  ScanFeatures merged(std::size_t scans) const;

 private:
  struct Entry {
    ScanFeatures features;     // in its own frame
    RigidTransform T_newest;   // T_newest_this
  };
  int scans_;
  std::deque<Entry> entries_;  // newest first
};

}  // namespace line_odom
