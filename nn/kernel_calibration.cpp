#include "nn/kernel_calibration.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <functional>
#include <limits>
#include <memory>
#include <vector>

#include "nn/conv3x3_amx.h"
#include "nn/conv3x3_bf16.h"
#include "nn/layers.h"
#include "nn/weight_cache.h"

namespace lidarsim::nn {

namespace {
std::atomic<long> g_calibrations{0};

// Finite values in [-1, 1) that are neither zero nor denormal, so no kernel takes a shortcut.
void fill_scratch(Tensor& t, unsigned salt) {
  float* p = t.data();
  for (std::size_t i = 0; i < t.numel(); ++i) {
    const unsigned v = (static_cast<unsigned>(i) + salt) * 2654435761u;
    p[i] = static_cast<float>((v >> 8) & 0xffff) / 32768.f - 1.f + 1.f / 65536.f;
  }
}

double time_once(const std::function<void()>& run) {
  const auto t0 = std::chrono::steady_clock::now();
  run();
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}
}  // namespace

PlanEntry calibrate(const ConvKey& key, ConvAlgo fp32_forward) {
  ++g_calibrations;
  const int n = key.n, ci = key.ci, co = key.co;
  Tensor in(n, ci, key.h, key.w), out, d_out(n, co, key.h, key.w), d_in;
  std::vector<float> weight(static_cast<std::size_t>(co) * ci * 9), bias(co), d_weight(weight.size()), d_bias(co);
  fill_scratch(in, 1);
  fill_scratch(d_out, 2);
  for (std::size_t i = 0; i < weight.size(); ++i) weight[i] = 0.05f * (static_cast<float>(i % 37) / 18.f - 1.f);
  std::fill(bias.begin(), bias.end(), 0.01f);
  conv2d_forward(out, in, weight.data(), bias.data(), co, 3, 1, true);  // the ReLU mask of the backward passes
  const bool wide = key.isa >= Isa::avx512;

  const std::vector<ConvAlgo> cands = candidates(key);
  std::vector<std::unique_ptr<detail::WeightCache>> caches;
  std::vector<std::function<void()>> runs;
  for (const ConvAlgo a : cands) {
    caches.push_back(std::make_unique<detail::WeightCache>());
    detail::WeightCache* cache = caches.back().get();
    detail::ConvSettings cs;
    const ConvAlgo fp32 = a == ConvAlgo::fp32 ? fp32_forward : a;
    cs.conv3x3 = fp32 == ConvAlgo::winograd ? detail::Conv3x3Path::winograd : detail::Conv3x3Path::direct;
    switch (key.pass) {
      case ConvPass::forward:
        runs.push_back([&, cs] { conv2d_forward(out, in, weight.data(), bias.data(), co, 3, 1, true, cs); });
        break;
      case ConvPass::input_grad:
        runs.push_back([&, cs] { conv2d_backward(&d_in, nullptr, nullptr, d_out, out, in, weight.data(), 3, 1, true, cs); });
        break;
      case ConvPass::weight_grad:  // below AVX-512 it stands for the whole backward pass (nn/kernel_plan.h)
        runs.push_back([&, cs, wide] {
          conv2d_backward(wide ? nullptr : &d_in, d_weight.data(), d_bias.data(), d_out, out, in, weight.data(), 3, 1,
                          true, cs);
        });
        break;
      case ConvPass::bf16_forward:
        if (a == ConvAlgo::amx) {
          runs.push_back([&, cache] {
            detail::conv3x3_amx_forward_cat(out.data(), in.data(), ci, nullptr, 0, n, key.h, key.w, weight.data(),
                                            bias.data(), co, true, cache);
          });
        } else if (a == ConvAlgo::avx512_bf16) {
          runs.push_back([&, cache] {
            detail::conv3x3_bf16_forward_cat(out.data(), in.data(), ci, nullptr, 0, n, key.h, key.w, weight.data(),
                                             bias.data(), co, true, cache);
          });
        } else {
          cs.weight_cache = cache;  // inference keeps its packed weights (nn/weight_cache.h)
          runs.push_back([&, cs] { conv2d_forward(out, in, weight.data(), bias.data(), co, 3, 1, true, cs); });
        }
        break;
    }
  }
  // One warm-up each (buffers, packed weights), then the timed runs, alternating.
  for (const auto& r : runs) r();
  std::vector<double> best(runs.size(), std::numeric_limits<double>::infinity());
  for (int rep = 0; rep < kTimedRuns; ++rep)
    for (std::size_t i = 0; i < runs.size(); ++i) best[i] = std::min(best[i], time_once(runs[i]));

  PlanEntry entry;
  std::size_t fastest = 0;
  for (std::size_t i = 0; i < runs.size(); ++i) {
    entry.seconds[to_string(cands[i])] = best[i];
    if (best[i] < best[fastest]) fastest = i;
  }
  // cands[0] is the rule's choice: it keeps a near tie, so noise alone never moves a layer.
  entry.algo = best[0] <= best[fastest] * (1 + kTieMargin) ? cands[0] : cands[fastest];
  return entry;
}

namespace testhook {
long calibrations() { return g_calibrations.load(); }
}  // namespace testhook

}  // namespace lidarsim::nn
