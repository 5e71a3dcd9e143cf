#pragma once
// Intensity drawn from a spread head's distribution (nn/heads.h log_scale_gaussian /
// log_scale_laplace) instead of its mean: what a measured scan's intensity scatters like.
// A draw depends only on (seed, frame, cell) through a counter-based hash (no generator state), so
// it is the same whatever the thread count, the order rows are computed in, or the frames run before.
#include <cstddef>
#include <cstdint>

#include "nn/heads.h"

namespace lidarsim::infer {

struct IntensitySampling {
  std::uint64_t seed = 1;
  // The sensor's intensity range: draws are clamped to it (lidar-train targets: KITTI's 0..1).
  float min = 0.f, max = 1.f;
  // Draw from the head's Laplace/Gaussian even when the checkpoint has a residual table (comparisons).
  bool parametric = false;
};

// With a zero head (nn/heads.h zero_logit): whether the cell's draw is the sensor's 0, with
// probability p_zero, from a uniform of (seed, frame, cell) independent of cell_uniforms' two.
bool draws_zero(double p_zero, const IntensitySampling& s, std::uint64_t frame, std::uint64_t cell);

// Two independent uniforms in (0, 1) for (seed, frame, cell).
void cell_uniforms(std::uint64_t seed, std::uint64_t frame, std::uint64_t cell, double& u1, double& u2);

// mean + a draw of the zero-centred distribution with this scale (sigma for Gaussian, b for
// Laplace), clamped to [s.min, s.max]. `spread` must be one of the two spread kinds.
float sample_intensity(nn::HeadKind spread, float mean, float scale, const IntensitySampling& s, std::uint64_t frame,
                       std::uint64_t cell);

// mean + scale * z with z drawn from the checkpoint's empirical residual table for this mean's bin
// (nn::SpreadResidual, inverse CDF of one uniform), clamped to [s.min, s.max], then put on the
// targets' grid (residual.target_step from s.min, when > 0): the values the sensor reports.
float sample_intensity_empirical(const nn::SpreadResidual& residual, float mean, float scale,
                                 const IntensitySampling& s, std::uint64_t frame, std::uint64_t cell);

}  // namespace lidarsim::infer
