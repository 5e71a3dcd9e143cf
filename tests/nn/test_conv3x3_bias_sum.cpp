// The bias gradient of the 3x3 conv is summed in a fixed order (each row from x = 0 up, the rows
// from y = 0 down, then the images), whatever vector tricks compute it (nn/conv3x3.cpp runs 16
// rows side by side): it must equal that plain ordered float sum bit for bit, on both paths
// (direct: sums of the padded copy; Winograd: sums of d_out itself), with and without the ReLU
// mask, on sizes that are not multiples of 16 rows or 16 columns.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <string>
#include <vector>

#include "conv_path.h"
#include "nn/conv3x3.h"

namespace lidarsim::nn {
namespace {

using conv_paths::Conv3x3PathGuard;
using detail::Conv3x3Path;

TEST(Conv3x3BiasSum, EqualsThePlainOrderedSumBitForBit) {
  if (!detail::conv3x3_available()) GTEST_SKIP() << "no AVX-512 kernels here (this CPU, or LIDARSIM_ISA): no conv3x3 kernel";
  std::mt19937 rng(11);
  std::normal_distribution<float> normal;
  struct Case {
    int n, ci, co, h, w;
  };
  for (const Case& c : {Case{2, 5, 7, 19, 37}, Case{1, 32, 32, 33, 70}})
    for (const Conv3x3Path path : {Conv3x3Path::direct, Conv3x3Path::winograd})
      for (const bool relu : {false, true}) {
        SCOPED_TRACE(std::string(conv_paths::path_name(path)) + " relu " + std::to_string(relu) + " h " +
                     std::to_string(c.h));
        Conv3x3PathGuard guard(path);
        const std::size_t in_n = static_cast<std::size_t>(c.n) * c.ci * c.h * c.w;
        const std::size_t out_n = static_cast<std::size_t>(c.n) * c.co * c.h * c.w;
        std::vector<float> in(in_n), out(out_n), d_out(out_n), weight(static_cast<std::size_t>(c.co) * c.ci * 9);
        for (float& v : in) v = normal(rng);
        for (float& v : out) v = std::max(normal(rng), 0.f);
        for (float& v : d_out) v = normal(rng);
        for (float& v : weight) v = 0.1f * normal(rng);
        std::vector<float> d_in(in_n), d_weight(weight.size(), 0.f), d_bias(static_cast<std::size_t>(c.co), 0.f);
        detail::conv3x3_backward(d_in.data(), d_weight.data(), d_bias.data(), d_out.data(), out.data(), in.data(),
                                 weight.data(), c.n, c.ci, c.h, c.w, c.co, relu);
        for (int o = 0; o < c.co; ++o) {
          float acc = 0.f;
          for (int img = 0; img < c.n; ++img) {
            const std::size_t base = (static_cast<std::size_t>(img) * c.co + o) * c.h * c.w;
            float total = 0.f;
            for (int y = 0; y < c.h; ++y) {
              float rs = 0.f;
              for (int x = 0; x < c.w; ++x) {
                const std::size_t i = base + static_cast<std::size_t>(y) * c.w + x;
                rs += !relu || out[i] > 0.f ? d_out[i] : 0.f;
              }
              total += rs;
            }
            acc += total;
          }
          EXPECT_EQ(d_bias[o], 0.f + acc) << "output channel " << o;
        }
      }
}

}  // namespace
}  // namespace lidarsim::nn
