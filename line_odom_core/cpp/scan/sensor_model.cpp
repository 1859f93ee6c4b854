#include "scan/sensor_model.hpp"

#include <stdexcept>

#include "common/types.hpp"

namespace line_odom {

namespace {

constexpr double kDeg = kPi / 180.0;

// Median elevation (deg) of each HDL-64E ring over the 30 shared KITTI scans, rings recovered from the
// azimuth wrap. KITTI's per-point elevations scatter by more than the beam spacing (intrinsic calibration,
// beam offsets), which is why the ring order is preferred whenever it is available.
constexpr double kKittiHdl64ElevationsDeg[64] = {
    2.630,   2.264,   2.023,   1.580,   1.288,   0.874,   0.605,   0.220,   -0.118,  -0.535,  -0.834,
    -1.174,  -1.548,  -1.875,  -2.171,  -2.525,  -2.833,  -3.228,  -3.512,  -3.906,  -4.204,  -4.576,
    -4.879,  -5.181,  -5.546,  -5.859,  -6.161,  -6.435,  -6.803,  -7.158,  -7.389,  -7.764,  -8.382,
    -8.901,  -9.361,  -9.751,  -10.214, -10.807, -11.301, -11.726, -12.179, -12.600, -13.137, -13.649,
    -14.224, -14.663, -15.152, -15.527, -16.157, -16.677, -17.246, -17.707, -18.202, -18.624, -19.058,
    -19.618, -20.112, -20.766, -21.227, -21.647, -22.071, -22.705, -23.152, -23.682};

}  // namespace

SensorModel sensor_preset(const std::string& name) {
  SensorModel m;
  if (name == "hdl64" || name == "kitti" || name == "kitti_hdl64") {
    m.name = "hdl64";
    m.rows = 64;
    m.cols = 2048;
    for (double e : kKittiHdl64ElevationsDeg) m.beam_elevations.push_back(e * kDeg);
    m.max_elevation = m.beam_elevations.front();
    m.min_elevation = m.beam_elevations.back();
    m.ring_order_from_azimuth_wrap = true;
  } else if (name == "vlp16") {
    m.name = "vlp16";
    m.rows = 16;
    m.cols = 1800;  // 0.2 deg at 10 Hz
    m.max_elevation = 15.0 * kDeg;
    m.min_elevation = -15.0 * kDeg;
  } else if (name == "os128") {
    m.name = "os128";
    m.rows = 128;
    m.cols = 1024;
    m.max_elevation = 22.5 * kDeg;
    m.min_elevation = -22.5 * kDeg;
  } else {
    throw std::invalid_argument("sensor: unknown preset '" + name + "' (expected hdl64, kitti, vlp16, os128)");
  }
  return m;
}

std::vector<std::string> sensor_preset_names() { return {"hdl64", "kitti", "vlp16", "os128"}; }

void validate_sensor_model(const SensorModel& m) {
  if (m.rows < 1 || m.cols < 1)
    throw std::invalid_argument("sensor model '" + m.name + "': rows and cols must be >= 1");
  if (!m.beam_elevations.empty()) {
    if (static_cast<int>(m.beam_elevations.size()) != m.rows)
      throw std::invalid_argument("sensor model '" + m.name + "': beam_elevations needs one entry per row");
    for (size_t i = 1; i < m.beam_elevations.size(); ++i)
      if (!(m.beam_elevations[i] < m.beam_elevations[i - 1]))
        throw std::invalid_argument("sensor model '" + m.name + "': beam_elevations must strictly decrease");
  } else if (m.rows > 1 && !(m.max_elevation > m.min_elevation)) {
    throw std::invalid_argument("sensor model '" + m.name + "': max_elevation must exceed min_elevation");
  }
}

}  // namespace line_odom
