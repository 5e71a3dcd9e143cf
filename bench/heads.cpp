// Cost of the extra heads (nn/heads.h): the recipe's UNet (docs/intensity.md: 27 input channels,
// base 8, depth 3) with one output (the mean, masked MSE) against K = 3 outputs (mean, return
// logit, log-scale: masked MSE + BCE on logits + Laplace or Gaussian NLL), in the same run:
//   train   one training step on a batch of crops (zero grads, forward, loss, backward, L2,
//           Adam), the recipe's batch 2 x 64 x 256; and the loss with its gradient alone
//   infer   one full frame (batch 1, 64 x 1024): predict, and for K = 3 the output transform
//           (sigmoid, exp of the clamped log-scale)
// The two models alternate within each round (K = 1 first in even rounds, K = 3 first in odd
// ones), so a change of the machine's load hits both; each round takes the median of --reps
// timed calls after --warmup untimed ones; reported are the median over rounds of each time and
// of the per-round ratio K3 / K1, with the process CPU time beside the wall time.
//   bench_heads [--rounds 5] [--reps 7] [--threads 2] [--out heads.json]
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cxxopts.hpp>
#include <fstream>
#include <functional>
#include <iostream>
#include <nlohmann/json.hpp>
#include <random>
#include <string>
#include <vector>

#include "common/atomic_file.h"
#include "common/error.h"
#include "nn/heads.h"
#include "nn/loss.h"
#include "nn/optim.h"
#include "nn/unet.h"

using namespace lidarsim;
using namespace lidarsim::nn;

namespace {

using Clock = std::chrono::steady_clock;

double cpu_now() {
  timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return t.tv_sec + 1e-9 * t.tv_nsec;
}

double median_of(std::vector<double> t) {
  std::sort(t.begin(), t.end());
  return t.size() % 2 ? t[t.size() / 2] : 0.5 * (t[t.size() / 2 - 1] + t[t.size() / 2]);
}

struct Timing {
  double wall = 0, cpu = 0;  // medians, s
};

Timing time_it(const std::function<void()>& fn, int warmup, int reps) {
  for (int i = 0; i < warmup; ++i) fn();
  std::vector<double> w, c;
  for (int i = 0; i < reps; ++i) {
    const auto t0 = Clock::now();
    const double c0 = cpu_now();
    fn();
    w.push_back(std::chrono::duration<double>(Clock::now() - t0).count());
    c.push_back(cpu_now() - c0);
  }
  return {median_of(w), median_of(c)};
}

std::string cpu_model() {
  std::ifstream in("/proc/cpuinfo");
  for (std::string line; std::getline(in, line);)
    if (line.rfind("model name", 0) == 0) return line.substr(line.find(':') + 2);
  return "unknown";
}

// One model with what its step and its inference need: inputs like an encoded PGM (normal
// values), a measured-like mask (70 % of cells with a return) and targets per head.
struct Setup {
  UNet model;
  Optimizer opt;
  std::vector<HeadKind> heads;
  Tensor x, frame, intensity, returned, m_int, m_all, y, dy, y_frame;

  Setup(const UNetConfig& cfg, int batch, int rows, int crop, int cols)
      : model(cfg), opt(OptimizerConfig{}, model.params().size()), heads(cfg.heads) {
    model.init(1);
    std::mt19937 rng(2);
    std::normal_distribution<float> normal;
    std::uniform_real_distribution<float> uniform;
    x.resize({batch, cfg.in_channels, rows, crop});
    frame.resize({1, cfg.in_channels, rows, cols});
    for (float& v : x) v = normal(rng);
    for (float& v : frame) v = normal(rng);
    const Shape one{batch, 1, rows, crop};
    intensity.resize(one), returned.resize(one), m_int.resize(one), m_all.resize(one);
    for (std::size_t i = 0; i < intensity.numel(); ++i) {
      const bool hit = uniform(rng) < 0.7f;
      intensity.data()[i] = uniform(rng);
      returned.data()[i] = hit ? 1.f : 0.f;
      m_int.data()[i] = hit ? 1.f : 0.f;
      m_all.data()[i] = 1.f;  // the return head sees every cell with geometry (here: all)
    }
  }

  void train_step() {
    model.params().zero_grads();
    model.forward(x, y);
    loss();
    model.backward(dy);
    l2_penalty(model.params(), 1e-6f, true);
    opt.step(model.params());
  }

  // The loss and its gradient on the last forward's output.
  void loss() {
    if (heads.empty()) {
      masked_mse(y, intensity, m_int, &dy);
    } else {
      std::vector<HeadTarget> t;
      for (HeadKind h : heads)
        t.push_back(h == HeadKind::return_logit ? HeadTarget{&returned, &m_all} : HeadTarget{&intensity, &m_int});
      heads_loss(heads, y, t, &dy);
    }
  }

  void infer() {
    model.predict(frame, y_frame);
    heads_output_transform(y_frame, heads);
  }
};

// Per round: wall time of each model's training step, loss and inference, and the K=3 / K=1
// ratios (wall and CPU) of the same round.
struct RoundSamples {
  std::vector<double> train1, train3, infer1, infer3, loss1, loss3;
  std::vector<double> train_ratio, infer_ratio, cpu_train_ratio, cpu_infer_ratio;
};

// The two models alternate which goes first, so a drift in the machine's speed hits both alike.
RoundSamples run_rounds(Setup& k1, Setup& k3, int rounds, int warmup, int reps) {
  RoundSamples s;
  for (int r = 0; r < rounds; ++r) {
    Timing t1, t3, i1, i3, l1, l3;
    auto run1 = [&] {
      t1 = time_it([&] { k1.train_step(); }, warmup, reps);
      l1 = time_it([&] { k1.loss(); }, warmup, reps);
      i1 = time_it([&] { k1.infer(); }, warmup, reps);
    };
    auto run3 = [&] {
      t3 = time_it([&] { k3.train_step(); }, warmup, reps);
      l3 = time_it([&] { k3.loss(); }, warmup, reps);
      i3 = time_it([&] { k3.infer(); }, warmup, reps);
    };
    if (r % 2 == 0) run1(), run3();
    else run3(), run1();
    s.loss1.push_back(l1.wall), s.loss3.push_back(l3.wall);
    s.train1.push_back(t1.wall), s.train3.push_back(t3.wall), s.infer1.push_back(i1.wall), s.infer3.push_back(i3.wall);
    s.train_ratio.push_back(t3.wall / t1.wall), s.infer_ratio.push_back(i3.wall / i1.wall);
    s.cpu_train_ratio.push_back(t3.cpu / t1.cpu), s.cpu_infer_ratio.push_back(i3.cpu / i1.cpu);
    std::fprintf(stderr, "round %d: train %.2f / %.2f ms (x%.3f), infer %.2f / %.2f ms (x%.3f)\n", r, 1e3 * t1.wall,
                 1e3 * t3.wall, t3.wall / t1.wall, 1e3 * i1.wall, 1e3 * i3.wall, i3.wall / i1.wall);
  }
  return s;
}

void print_table(const RoundSamples& s, int batch, int rows, int crop, int cols) {
  std::printf("%-40s %10s %10s %8s %8s\n", "median over rounds", "K=1 ms", "K=3 ms", "ratio", "cpu ratio");
  std::printf("%-40s %10.2f %10.2f %8.3f %8.3f\n",
              ("train step, batch " + std::to_string(batch) + " x " + std::to_string(rows) + " x " + std::to_string(crop)).c_str(),
              1e3 * median_of(s.train1), 1e3 * median_of(s.train3), median_of(s.train_ratio), median_of(s.cpu_train_ratio));
  std::printf("%-40s %10.2f %10.2f   (of the step: %.1f %% / %.1f %%)\n", "  of which the loss and its gradient",
              1e3 * median_of(s.loss1), 1e3 * median_of(s.loss3), 100 * median_of(s.loss1) / median_of(s.train1),
              100 * median_of(s.loss3) / median_of(s.train3));
  std::printf("%-40s %10.2f %10.2f %8.3f %8.3f\n", ("inference, 1 x " + std::to_string(rows) + " x " + std::to_string(cols)).c_str(),
              1e3 * median_of(s.infer1), 1e3 * median_of(s.infer3), median_of(s.infer_ratio), median_of(s.cpu_infer_ratio));
}

nlohmann::json results_json(const RoundSamples& s) {
  nlohmann::json j;
  j["train_ms"] = {{"k1", 1e3 * median_of(s.train1)}, {"k3", 1e3 * median_of(s.train3)}, {"ratio", median_of(s.train_ratio)},
                   {"cpu_ratio", median_of(s.cpu_train_ratio)}, {"ratios", s.train_ratio}};
  j["loss_ms"] = {{"k1", 1e3 * median_of(s.loss1)}, {"k3", 1e3 * median_of(s.loss3)}};
  j["infer_ms"] = {{"k1", 1e3 * median_of(s.infer1)}, {"k3", 1e3 * median_of(s.infer3)}, {"ratio", median_of(s.infer_ratio)},
                   {"cpu_ratio", median_of(s.cpu_infer_ratio)}, {"ratios", s.infer_ratio}};
  return j;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    cxxopts::Options options("bench_heads", "the recipe's UNet with 1 output against 3 heads, same run");
    options.add_options()
      ("rounds", "alternating rounds (median over them)", cxxopts::value<int>()->default_value("5"))
      ("reps", "timed calls per model and round (median)", cxxopts::value<int>()->default_value("7"))
      ("warmup", "untimed calls per model and round", cxxopts::value<int>()->default_value("2"))
      ("threads", "OpenMP threads", cxxopts::value<int>()->default_value("2"))
      ("in-channels", "input channels (the shipped model's encoder: 27)", cxxopts::value<int>()->default_value("27"))
      ("base", "UNet base width", cxxopts::value<int>()->default_value("8"))
      ("depth", "UNet depth", cxxopts::value<int>()->default_value("3"))
      ("batch", "training batch", cxxopts::value<int>()->default_value("2"))
      ("rows", "rows (lasers)", cxxopts::value<int>()->default_value("64"))
      ("crop", "training crop columns", cxxopts::value<int>()->default_value("256"))
      ("cols", "inference frame columns", cxxopts::value<int>()->default_value("1024"))
      ("spread", "spread head: laplace or gaussian", cxxopts::value<std::string>()->default_value("laplace"))
      ("out", "also write the results as JSON here", cxxopts::value<std::string>())
      ("h,help", "this help");
    const auto args = options.parse(argc, argv);
    if (args.count("help")) {
      std::cout << options.help() << "\n";
      return 0;
    }
    const int rounds = args["rounds"].as<int>(), reps = args["reps"].as<int>(), warmup = args["warmup"].as<int>();
    if (rounds < 1 || reps < 1 || warmup < 0) throw Error("bench_heads: --rounds and --reps >= 1, --warmup >= 0");
    const std::string spread = args["spread"].as<std::string>();
    if (spread != "laplace" && spread != "gaussian")
      throw Error("bench_heads: --spread: expected laplace or gaussian, got " + spread);
    omp_set_num_threads(args["threads"].as<int>());

    UNetConfig one;
    one.in_channels = args["in-channels"].as<int>();
    one.base = args["base"].as<int>();
    one.depth = args["depth"].as<int>();
    UNetConfig three = one;
    three.out_channels = 3;
    three.heads = {HeadKind::mean, HeadKind::return_logit,
                   spread == "laplace" ? HeadKind::log_scale_laplace : HeadKind::log_scale_gaussian};
    const int batch = args["batch"].as<int>(), rows = args["rows"].as<int>(), crop = args["crop"].as<int>(),
              cols = args["cols"].as<int>();
    Setup k1(one, batch, rows, crop, cols), k3(three, batch, rows, crop, cols);

    const RoundSamples samples = run_rounds(k1, k3, rounds, warmup, reps);
    const std::string cpu = cpu_model();
    std::printf("CPU: %s, %d threads; UNet %d -> 1 | 3 (mean, return_logit, log_scale_%s), base %d, depth %d\n",
                cpu.c_str(), args["threads"].as<int>(), one.in_channels, spread.c_str(), one.base, one.depth);
    print_table(samples, batch, rows, crop, cols);
    if (args.count("out")) {
      nlohmann::json j = results_json(samples);
      j["cpu"] = cpu;
      j["threads"] = args["threads"].as<int>();
      j["rounds"] = rounds;
      j["reps"] = reps;
      j["spread"] = spread;
      write_file_atomically(args["out"].as<std::string>(), j.dump(2) + "\n");
    }
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 1;
  }
}
