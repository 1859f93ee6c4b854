// splitmix64 (Steele, Lea, Flood 2014): the seeds of the RANSAC generator and a well-spread hash of voxel keys.
#pragma once

#include <cstdint>

namespace line_odom {

constexpr std::uint64_t kSplitmix64Gamma = 0x9e3779b97f4a7c15ULL;

// splitmix64's output function: every input bit reaches every output bit.
inline std::uint64_t splitmix64_mix(std::uint64_t z) {
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

}  // namespace line_odom
