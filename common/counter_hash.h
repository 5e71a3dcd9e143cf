#pragma once
// SplitMix64 as a counter-based hash: the simulation's random draws per (seed, frame, cell) and
// the training's per-(seed, epoch, step) choices are pure functions of their key, so they come out
// the same whatever the thread count or the order the work runs in.
#include <cstdint>

namespace lidarsim {

inline constexpr std::uint64_t kSplitMixGamma = 0x9e3779b97f4a7c15ULL;

// SplitMix64's finaliser: a bijective mix whose outputs for consecutive inputs are independent
// enough for Monte Carlo draws.
inline std::uint64_t mix64(std::uint64_t z) {
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

// One SplitMix64 step from state x: the finaliser of x + gamma.
inline std::uint64_t splitmix64(std::uint64_t x) { return mix64(x + kSplitMixGamma); }

}  // namespace lidarsim
