// Direct against Winograd F(4x4, 3x3) for each 3x3 conv shape of "unet-ref" (3 -> 1 channels,
// base 16, depth 4, rows x cols): forward (bias + ReLU), input gradient and weight gradient
// (ReLU-masked by the direct forward's output), median process CPU time per call over --reps (--wall: wall time),
// with the CPU time of the whole run and the load average, and the largest
// difference between the two paths relative to the largest output. The automatic rule in
// nn/conv3x3.cpp (conv3x3_takes_winograd) came from this table, and from the same split measured
// in the network (LIDARSIM_PROFILE=cpu). Where the CPU has AVX-512 BF16,
// also the bf16 inference kernel's forward pass (nn/conv3x3_bf16.h): its time, its speed-up over
// the fp32 direct and Winograd forward passes, and its difference from the direct output; the
// rule conv3x3_takes_bf16 comes from these columns. Where the CPU has AMX-BF16, also the AMX
// kernel's forward pass (nn/conv3x3_amx.h): its time, its speed-up over the fp32 direct,
// Winograd and AVX-512 BF16 forward passes, and its difference from the direct output; the rule
// conv3x3_takes_amx comes from these. Both bf16 kernels keep their packed weights in a
// WeightCache, as UNet::predict does.
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <cxxopts.hpp>
#include <fstream>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "common/error.h"
#include "nn/conv3x3.h"
#include "nn/conv3x3_amx.h"
#include "nn/conv3x3_bf16.h"
#include "nn/kernel_cache.h"
#include "nn/kernel_plan.h"
#include "nn/layers.h"
#include "nn/weight_cache.h"
#include "nn/winograd.h"

using namespace lidarsim;
using namespace lidarsim::nn;

namespace {

double cpu_seconds() {
  timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return t.tv_sec + 1e-9 * t.tv_nsec;
}

double wall_seconds() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

// Median over reps of the call's process CPU time (all threads; on a loaded machine wall time
// mostly measures waiting for a core) or, with wall, of its wall time.
double median_seconds(const std::function<void()>& fn, int reps, bool wall) {
  fn();  // warm-up: scratch buffers grow here
  std::vector<double> t;
  for (int i = 0; i < reps; ++i) {
    const double t0 = wall ? wall_seconds() : cpu_seconds();
    fn();
    t.push_back((wall ? wall_seconds() : cpu_seconds()) - t0);
  }
  std::sort(t.begin(), t.end());
  return t.size() % 2 ? t[t.size() / 2] : 0.5 * (t[t.size() / 2 - 1] + t[t.size() / 2]);
}

std::string loadavg() {
  std::ifstream in("/proc/loadavg");
  std::string a, b, c;
  in >> a >> b >> c;
  return a + " " + b + " " + c;
}

double rel_diff(const Tensor& a, const Tensor& ref) {
  double d = 0, s = 0;
  for (std::size_t i = 0; i < ref.numel(); ++i) {
    d = std::max(d, static_cast<double>(std::abs(a.data()[i] - ref.data()[i])));
    s = std::max(s, static_cast<double>(std::abs(ref.data()[i])));
  }
  return d / std::max(s, 1e-30);
}

// One conv shape: forward, input gradient and weight gradient on both paths (direct, Winograd),
// and bf16 forward where the CPU has it; prints one table row.
struct ShapeRun {
  int reps = 5;
  bool wall = false, fwd_only = false, bf16 = false, amx = false;
};

void measure_shape(int n, int ci, int co, int h, int w, const ShapeRun& run, std::mt19937& rng,
                   std::normal_distribution<float>& normal) {
  const int reps = run.reps;
  const bool wall = run.wall, fwd_only = run.fwd_only, bf16 = run.bf16, amx = run.amx;
  Tensor x(n, ci, h, w);
  for (float& v : x) v = std::max(normal(rng), 0.f);
  std::vector<float> wt(static_cast<std::size_t>(co) * ci * 9), bias(static_cast<std::size_t>(co), 0.01f);
  for (float& v : wt) v = normal(rng) * std::sqrt(2.f / (9.f * ci));
  Tensor y[2], d_in[2], g(n, co, h, w);
  for (float& v : g) v = normal(rng);
  std::vector<float> d_w[2];
  double t_fwd[2], t_dgr[2], t_wgr[2];
  for (int p = 0; p < 2; ++p) {
    detail::set_conv3x3_path(p ? detail::Conv3x3Path::winograd : detail::Conv3x3Path::direct);
    t_fwd[p] = median_seconds([&] { conv2d_forward(y[p], x, wt.data(), bias.data(), co, 3, 1, true); }, reps, wall);
    t_dgr[p] = t_wgr[p] = 0;
    d_w[p].assign(wt.size(), 0.f);
    if (fwd_only) continue;
    t_dgr[p] = median_seconds(
        [&] { conv2d_backward(&d_in[p], nullptr, nullptr, g, y[0], x, wt.data(), 3, 1, true); }, reps, wall);
    d_w[p].assign(wt.size(), 0.f);
    t_wgr[p] = median_seconds(
        [&] {
          std::fill(d_w[p].begin(), d_w[p].end(), 0.f);
          conv2d_backward(nullptr, d_w[p].data(), nullptr, g, y[0], x, wt.data(), 3, 1, true);
        },
        reps, wall);
  }
  Tensor y16(n, co, h, w), yamx(n, co, h, w);
  detail::WeightCache cache16, cache_amx;
  const double t_b16 =
      bf16 ? median_seconds(
                 [&] {
                   detail::conv3x3_bf16_forward_cat(y16.data(), x.data(), ci, nullptr, 0, n, h, w, wt.data(),
                                                    bias.data(), co, true, &cache16);
                 },
                 reps, wall)
           : 0;
  const double t_amx =
      amx ? median_seconds(
                [&] {
                  detail::conv3x3_amx_forward_cat(yamx.data(), x.data(), ci, nullptr, 0, n, h, w, wt.data(),
                                                  bias.data(), co, true, &cache_amx);
                },
                reps, wall)
          : 0;
  Tensor dw0(1, 1, 1, static_cast<int>(wt.size())), dw1(1, 1, 1, static_cast<int>(wt.size()));
  std::copy(d_w[0].begin(), d_w[0].end(), dw0.begin());
  std::copy(d_w[1].begin(), d_w[1].end(), dw1.begin());
  std::printf("%-5d %4d %4d %4d %5d %8.3f %8.3f %7.2f %8.3f %8.3f %7.2f %8.3f %8.3f %7.2f %8.1e %8.1e %8.1e", n,
              ci, co, h, w, 1e3 * t_fwd[0], 1e3 * t_fwd[1], t_fwd[0] / t_fwd[1], 1e3 * t_dgr[0],
              1e3 * t_dgr[1], t_dgr[0] / t_dgr[1], 1e3 * t_wgr[0], 1e3 * t_wgr[1], t_wgr[0] / t_wgr[1],
              rel_diff(y[1], y[0]), rel_diff(d_in[1], d_in[0]), rel_diff(dw1, dw0));
  if (bf16)
    std::printf(" %8.3f %8.2f %8.2f %9.1e", 1e3 * t_b16, t_fwd[0] / t_b16, t_fwd[1] / t_b16,
                rel_diff(y16, y[0]));
  if (amx)
    std::printf(" %8.3f %7.2f %7.2f %8.2f %8.1e", 1e3 * t_amx, t_fwd[0] / t_amx, t_fwd[1] / t_amx, t_b16 / t_amx,
                rel_diff(yamx, y[0]));
  std::printf("\n");
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  try {
    cxxopts::Options options("bench_conv3x3", "3x3 convs of unet-ref: direct vs Winograd per layer shape");
    options.add_options()
      ("reps", "timed repetitions (median)", cxxopts::value<int>()->default_value("5"))
      ("threads", "OpenMP threads", cxxopts::value<int>()->default_value("2"))
      ("batch", "batch sizes, comma separated", cxxopts::value<std::vector<int>>()->default_value("1,4"))
      ("rows", "input rows", cxxopts::value<int>()->default_value("64"))
      ("cols", "input columns", cxxopts::value<int>()->default_value("1024"))
      ("level", "only this UNet level (-1: all)", cxxopts::value<int>()->default_value("-1"))
      ("wall", "time wall clock instead of process CPU time")
      ("forward-only", "time only the forward passes (gradient columns print 0)")
      ("kernels", "calibrated: instead of the table, the plan a calibrated model picks for each shape and pass "
       "(nn/kernel_plan.h), with each candidate's minimum wall time and the rule's choice; read from the kernel cache "
       "where it has the shape (point LIDARSIM_KERNEL_CACHE at an empty folder to measure afresh)",
       cxxopts::value<std::string>())
      ("h,help", "show help");
    const auto opt = options.parse(argc, argv);
    if (opt.count("help")) {
      std::printf("%s\n", options.help().c_str());
      return 0;
    }
    if (!detail::winograd_available()) throw Error("bench_conv3x3: built without AVX2 kernels: no Winograd path");
    const int reps = opt["reps"].as<int>(), rows = opt["rows"].as<int>(), cols = opt["cols"].as<int>();
    if (reps < 1) throw Error("--reps: expected >= 1");
    omp_set_num_threads(opt["threads"].as<int>());
    const std::string load_before = loadavg();
    const double cpu0 = cpu_seconds();
    const bool wall = opt.count("wall") > 0, fwd_only = opt.count("forward-only") > 0;
    const int base = 16, depth = 4;
    const bool bf16 = detail::conv3x3_bf16_available(), amx = detail::conv3x3_amx_available();
    if (opt.count("kernels")) {
      if (parse_plan_mode(opt["kernels"].as<std::string>(), "bench_conv3x3: --kernels") != PlanMode::calibrated)
        throw Error("bench_conv3x3: --kernels: only calibrated prints a plan (rule is the table's rule column)");
      KernelPlan plan(PlanMode::calibrated);
      int changed = 0, total = 0;
      const double wall0 = wall_seconds();
      for (int n : opt["batch"].as<std::vector<int>>())
        for (int l = 0; l <= depth; ++l) {
          const int c = base << l, h = rows >> l, w = cols >> l;
          std::vector<std::pair<int, int>> shapes{{l == 0 ? 3 : c / 2, c}, {c, c}};
          if (l < depth) shapes.push_back({2 * c, c});
          for (const auto& [ci, co] : shapes)
            for (const ConvPass pass : {ConvPass::forward, ConvPass::input_grad, ConvPass::weight_grad, ConvPass::bf16_forward}) {
              if (pass == ConvPass::bf16_forward && !bf16) continue;
              if (pass == ConvPass::input_grad && l == 0 && ci == 3) continue;  // enc0.conv1 has no input gradient
              const ConvKey key{pass, n, ci, co, h, w, active_isa()};
              changed += plan.lookup(key) != rule_choice(key);
              ++total;
            }
        }
      std::printf("kernel plan (calibrated) on %s, %s, %d threads; cache %s; %.1f s\n", cpu_name().c_str(),
                  to_string(active_isa()), opt["threads"].as<int>(), kernel_cache_path(active_isa()).c_str(),
                  wall_seconds() - wall0);
      for (const auto& [key, entry] : plan.entries()) {
        const ConvAlgo rule = rule_choice(key);
        std::printf("  %-12s n%d %3d->%-3d %2dx%-4d %-11s (rule %s)", to_string(key.pass), key.n, key.ci, key.co, key.h,
                    key.w, to_string(entry.algo), to_string(rule));
        for (const auto& [name, sec] : entry.seconds) std::printf("  %s %.3f ms", name.c_str(), sec * 1e3);
        std::printf("\n");
      }
      std::printf("%d of %d choices differ from the rule; load average before / after: %s / %s\n", changed, total,
                  load_before.c_str(), loadavg().c_str());
      return 0;
    }
    if (!detail::conv3x3_available())
      std::printf("(no AVX-512 kernels at this level: \"dir\" is im2col + Eigen GEMM, \"win\" the AVX2 Winograd port)\n");
    std::printf("%-5s %4s %4s %4s %5s %8s %8s %7s %8s %8s %7s %8s %8s %7s %8s %8s %8s", "batch", "ci", "co", "h", "w",
                "fwd dir", "fwd win", "speedup", "dgr dir", "dgr win", "speedup", "wgr dir", "wgr win", "speedup",
                "fwd diff", "dgr diff", "wgr diff");
    if (bf16) std::printf(" %8s %8s %8s %9s", "fwd bf16", "dir/bf16", "win/bf16", "bf16 diff");
    if (amx) std::printf(" %8s %7s %7s %8s %8s", "fwd amx", "dir/amx", "win/amx", "bf16/amx", "amx diff");
    std::printf("\n");
    std::mt19937 rng(1);
    std::normal_distribution<float> normal;
    const ShapeRun run{reps, wall, fwd_only, bf16, amx};
    for (int n : opt["batch"].as<std::vector<int>>()) {
      for (int l = 0; l <= depth; ++l) {
        if (opt["level"].as<int>() >= 0 && l != opt["level"].as<int>()) continue;
        const int c = base << l, h = rows >> l, w = cols >> l;
        std::vector<std::pair<int, int>> shapes{{l == 0 ? 3 : c / 2, c}, {c, c}};
        if (l < depth) shapes.push_back({2 * c, c});
        for (const auto& [ci, co] : shapes) measure_shape(n, ci, co, h, w, run, rng, normal);
      }
    }
    std::printf("%s in ms (median of %d); process CPU time %.1f s; load average before / after: %s / %s\n", wall ? "wall times" : "CPU times (all threads)",
                reps, cpu_seconds() - cpu0, load_before.c_str(), loadavg().c_str());
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
