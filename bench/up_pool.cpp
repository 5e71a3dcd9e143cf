// The UNet's non-3x3 layers at each level of "unet-ref" (base 16, depth 4, rows x cols): the 2x2
// transposed convolution (forward with bias; backward: input, weight and bias gradients) and the
// 2x2 max-pool (forward, backward). Median process CPU time per call over --reps (--wall: wall
// time) and the rate in GFLOP/s or GB/s, so a change to these kernels is judged per shape.
// These layers move more bytes per FLOP than the 3x3 convolutions; bench_unet_vs_torch times them
// inside the whole model beside PyTorch.
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <cxxopts.hpp>
#include <functional>
#include <iostream>
#include <random>
#include <vector>

#include "common/error.h"
#include "nn/layers.h"

using namespace lidarsim;
using namespace lidarsim::nn;

namespace {

double now(bool wall) {
  if (wall) return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
  timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return t.tv_sec + 1e-9 * t.tv_nsec;
}

double median_seconds(const std::function<void()>& fn, int reps, bool wall) {
  fn();  // warm-up: outputs and scratch grow here
  std::vector<double> t;
  for (int i = 0; i < reps; ++i) {
    const double t0 = now(wall);
    fn();
    t.push_back(now(wall) - t0);
  }
  std::sort(t.begin(), t.end());
  return t[t.size() / 2];
}

void fill(Tensor& t, std::mt19937& rng) {
  std::normal_distribution<float> d(0.f, 1.f);
  for (std::size_t i = 0; i < t.numel(); ++i) t.data()[i] = d(rng);
}

}  // namespace

int main(int argc, char** argv) {
  try {
    cxxopts::Options options("bench_up_pool", "UNet transposed conv 2x2 and max-pool 2x2, per level");
    options.add_options()
      ("reps", "timed calls per row (median)", cxxopts::value<int>()->default_value("21"))
      ("threads", "OpenMP threads", cxxopts::value<int>()->default_value("2"))
      ("rows", "input rows of the model", cxxopts::value<int>()->default_value("64"))
      ("cols", "input columns of the model", cxxopts::value<int>()->default_value("1024"))
      ("batch", "images per call", cxxopts::value<int>()->default_value("1"))
      ("wall", "wall time instead of process CPU time")
      ("h,help", "show help");
    const auto opt = options.parse(argc, argv);
    if (opt.count("help")) {
      std::cout << options.help() << "\n";
      return 0;
    }
    const int reps = opt["reps"].as<int>(), rows = opt["rows"].as<int>(), cols = opt["cols"].as<int>();
    const int n = opt["batch"].as<int>();
    if (reps < 1) throw Error("--reps: expected >= 1");
    if (n < 1) throw Error("--batch: expected >= 1");
    if (rows < 16 || cols < 16) throw Error("--rows/--cols: expected >= 16 (depth 4 halves four times)");
    const bool wall = opt.count("wall") > 0;
    omp_set_num_threads(opt["threads"].as<int>());
    std::mt19937 rng(7);
    std::printf("%-10s %-22s %12s %12s %10s\n", "layer", "shape (N C H W in)", "forward ms", "backward ms", "fwd rate");
    double total_f = 0, total_b = 0;
    for (int l = 0; l < 4; ++l) {
      // up of level l: [n, 2c, h/2, w/2] -> [n, c, h, w]
      const int c = 16 << l, h = rows >> l, w = cols >> l;
      Tensor in(Shape{n, 2 * c, h / 2, w / 2}), out, d_in, d_out(Shape{n, c, h, w});
      std::vector<float> wgt(static_cast<std::size_t>(2 * c) * c * 4), bias(c), d_w(wgt.size()), d_b(c);
      fill(in, rng);
      fill(d_out, rng);
      std::normal_distribution<float> d(0.f, 0.1f);
      for (float& v : wgt) v = d(rng);
      for (float& v : bias) v = d(rng);
      const double f = median_seconds([&] { conv_transpose2x2_forward(out, in, wgt.data(), bias.data(), c, h, w); },
                                      reps, wall);
      const double b = median_seconds(
          [&] { conv_transpose2x2_backward(d_in, d_w.data(), d_b.data(), d_out, in, wgt.data()); }, reps, wall);
      const double flops = 2.0 * n * (h / 2) * (w / 2) * (2 * c) * c * 4;
      std::printf("up%-8d %-22s %12.3f %12.3f %7.1f GF\n", l,
                  (std::to_string(n) + " " + std::to_string(2 * c) + " " + std::to_string(h / 2) + " " +
                   std::to_string(w / 2))
                      .c_str(),
                  1e3 * f, 1e3 * b, flops / f * 1e-9);
      total_f += f;
      total_b += b;
    }
    for (int l = 0; l < 4; ++l) {
      // pool below level l: [n, c, h, w] -> [n, c, h/2, w/2]
      const int c = 16 << l, h = rows >> l, w = cols >> l;
      Tensor in(Shape{n, c, h, w}), out, d_in(Shape{n, c, h, w}), d_out(Shape{n, c, h / 2, w / 2});
      std::vector<std::int32_t> argmax;
      fill(in, rng);
      fill(d_out, rng);
      const double f = median_seconds([&] { max_pool2x2_forward(out, argmax, in); }, reps, wall);
      const double b = median_seconds([&] { max_pool2x2_backward(d_in, d_out, argmax, in.shape(), false); }, reps, wall);
      const double bytes = 4.0 * in.numel() * 1.5;
      std::printf("pool%-6d %-22s %12.3f %12.3f %7.1f GB/s\n", l,
                  (std::to_string(n) + " " + std::to_string(c) + " " + std::to_string(h) + " " + std::to_string(w)).c_str(),
                  1e3 * f, 1e3 * b, bytes / f * 1e-9);
      total_f += f;
      total_b += b;
    }
    std::printf("total      %-22s %12.3f %12.3f   (%s time)\n", "", 1e3 * total_f, 1e3 * total_b, wall ? "wall" : "CPU");
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 1;
  }
}
