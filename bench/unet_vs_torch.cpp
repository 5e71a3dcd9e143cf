// Speed of the engine against PyTorch on "unet-ref" (3 -> 1 channels, base 16, depth 4,
// rows x cols, masked MSE + L2, Adam), measured in the same run on the same machine:
// a training step and inference at batch 1 and 4, median over --reps after
// --warmup untimed runs. PyTorch runs as a subprocess (bench/torch_unet_bench.py) with
// OMP_NUM_THREADS set and OPENBLAS_CORETYPE / OPENBLAS_L2_SIZE unset for it alone, so it gets
// OpenBLAS's own choice of kernels. A 4096^3 fp32 GEMM through Eigen gives the machine's
// practical peak for context. Where the CPU has AVX-512 BF16, also our bf16 inference
// (nn/precision.h) at batch 1 and 4, against PyTorch's fp32 inference (the peer) and, as an
// extra column, PyTorch's own bf16 (torch.autocast on the CPU). The peer runs once per OpenMP
// wait policy (--torch-wait-policies, default passive and active) and the fastest run counts per
// row: our layers spin briefly between regions on their own (nn/parallel.h) whatever the policy
// says, so the peer gets its best wait policy too.
#include <omp.h>

#include <Eigen/Core>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cxxopts.hpp>
#include <fstream>
#include <functional>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "common/atomic_file.h"
#include "common/error.h"
#include "nn/cpu_features.h"
#include "nn/loss.h"
#include "nn/optim.h"
#include "nn/precision.h"
#include "nn/unet.h"

#ifndef LIDARSIM_SOURCE_DIR
#define LIDARSIM_SOURCE_DIR "."
#endif

using namespace lidarsim;
using namespace lidarsim::nn;

namespace {

using Clock = std::chrono::steady_clock;

struct Timing {
  double median = 0, min = 0, cpu = 0;
};

double cpu_now() {
  timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return t.tv_sec + 1e-9 * t.tv_nsec;
}

double median_of(std::vector<double> t) {
  std::sort(t.begin(), t.end());
  return t.size() % 2 ? t[t.size() / 2] : 0.5 * (t[t.size() / 2 - 1] + t[t.size() / 2]);
}

// Median (the reported number) and minimum (less sensitive to a busy machine) of the wall time
// over reps, and the median process CPU time (all threads: what a loaded machine cannot inflate
// by descheduling us, though shared caches still cost).
Timing time_it(const std::function<void()>& fn, int warmup, int reps) {
  for (int i = 0; i < warmup; ++i) fn();
  std::vector<double> t, c;
  for (int i = 0; i < reps; ++i) {
    const auto t0 = Clock::now();
    const double c0 = cpu_now();
    fn();
    t.push_back(std::chrono::duration<double>(Clock::now() - t0).count());
    c.push_back(cpu_now() - c0);
  }
  return {median_of(t), *std::min_element(t.begin(), t.end()), median_of(c)};
}

struct Batch {
  Tensor x, target, mask;
};

Batch make_batch(int n, int channels, int rows, int cols, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> normal;
  std::uniform_real_distribution<float> uniform;
  Batch b{Tensor(n, channels, rows, cols), Tensor(n, 1, rows, cols), Tensor(n, 1, rows, cols)};
  for (float& v : b.x) v = normal(rng);
  for (float& v : b.target) v = uniform(rng);
  for (float& v : b.mask) v = uniform(rng) < 0.7f ? 1.f : 0.f;
  return b;
}

// 4096^3 fp32 through Eigen, threads splitting the columns of C (Eigen itself is built with
// EIGEN_DONT_PARALLELIZE, as in the engine).
double gemm_seconds(int size, int threads, int reps) {
  Eigen::MatrixXf a = Eigen::MatrixXf::Random(size, size), b = Eigen::MatrixXf::Random(size, size);
  Eigen::MatrixXf c(size, size);
  auto run = [&] {
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int t = 0; t < threads; ++t) {
      const Eigen::Index begin = static_cast<Eigen::Index>(size) * t / threads;
      const Eigen::Index end = static_cast<Eigen::Index>(size) * (t + 1) / threads;
      c.middleCols(begin, end - begin).noalias() = a * b.middleCols(begin, end - begin);
    }
  };
  return time_it(run, 1, reps).median;
}

std::string shell_quote(const std::string& s) {
  std::string out = "'";
  for (char ch : s) out += ch == '\'' ? std::string("'\\''") : std::string(1, ch);
  return out + "'";
}

// Runs the PyTorch peer and returns its JSON (the last line it prints on stdout).
nlohmann::json run_torch(const std::string& python, const std::string& script, int threads, int rows, int cols,
                         int reps, int warmup, float lambda, const std::string& settings, bool bf16,
                         const std::string& wait_policy) {
  std::ostringstream cmd;
  cmd << "env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE OMP_NUM_THREADS=" << threads
      << " OMP_WAIT_POLICY=" << shell_quote(wait_policy) << " " << shell_quote(python)
      << " " << shell_quote(script) << " --threads " << threads << " --rows " << rows << " --cols " << cols
      << " --reps " << reps << " --warmup " << warmup << " --lam " << lambda << " --settings " << shell_quote(settings)
      << (bf16 ? " --bf16" : "");
  std::cerr << "bench: running PyTorch: " << cmd.str() << "\n";
  FILE* pipe = ::popen(cmd.str().c_str(), "r");
  if (!pipe) throw Error(script + ": cannot start " + python);
  std::string out;
  char buf[4096];
  while (std::fgets(buf, sizeof buf, pipe)) out += buf;
  const int status = ::pclose(pipe);
  if (status != 0) throw Error(script + ": PyTorch peer failed (exit status " + std::to_string(status) + ")");
  const std::size_t end = out.find_last_not_of("\n");
  const std::size_t start = out.rfind('\n', end);
  const std::string last = out.substr(start == std::string::npos ? 0 : start + 1);
  try {
    return nlohmann::json::parse(last);
  } catch (const std::exception& e) {
    throw Error(script + ": output: expected one JSON line at the end, got \"" + last + "\"");
  }
}

std::string loadavg() {
  std::ifstream in("/proc/loadavg");
  std::string a, b, c;
  in >> a >> b >> c;
  return a + " " + b + " " + c;
}

// The options, checked before anything is timed: a bad value must not cost a run.
struct BenchOptions {
  int reps = 7, warmup = 2, threads = 2, rows = 64, cols = 1024, gemm_n = 4096, only_batch = 0;
  float lambda = 1e-4f;
  std::string python, torch_script, torch_settings, json;
  std::vector<std::string> wait_policies;
  bool with_torch = true, want_bf16 = true, infer_only = false, bf16_only = false, train_only = false;
  PlanMode kernels = PlanMode::rule;  // the model's kernel plan (nn/kernel_plan.h)
};

// Returns nullopt after printing the help.
std::optional<BenchOptions> parse_options(int argc, char** argv) {
  cxxopts::Options options("bench_unet_vs_torch", "unet-ref: engine vs PyTorch, same run, same threads");
  options.add_options()
    ("reps", "timed repetitions per row (median)", cxxopts::value<int>()->default_value("7"))
    ("warmup", "untimed runs before timing", cxxopts::value<int>()->default_value("2"))
    ("threads", "OpenMP threads for both engines", cxxopts::value<int>()->default_value("2"))
    ("rows", "input rows (beams)", cxxopts::value<int>()->default_value("64"))
    ("cols", "input columns (azimuth bins)", cxxopts::value<int>()->default_value("1024"))
    ("lambda", "L2 weight", cxxopts::value<float>()->default_value("0.0001"))
    ("python", "Python with torch", cxxopts::value<std::string>()->default_value("/usr/bin/python3"))
    ("torch-script", "the PyTorch peer",
     cxxopts::value<std::string>()->default_value(LIDARSIM_SOURCE_DIR "/bench/torch_unet_bench.py"))
    ("torch-settings", "PyTorch settings to try, the fastest counts per row (default, no_onednn, channels_last)",
     cxxopts::value<std::string>()->default_value("default,no_onednn,channels_last"))
    ("torch-wait-policies", "OMP_WAIT_POLICY values to run the PyTorch peer under, the fastest counts per row",
     cxxopts::value<std::string>()->default_value("passive,active"))
    ("no-torch", "time only our engine")
    ("no-bf16", "leave out the bf16 inference rows (they need AVX-512 BF16)")
    ("infer-only", "only the inference rows (with --no-torch: e.g. for LIDARSIM_PROFILE=cpu)")
    ("bf16-only", "only the bf16 inference rows (with --no-torch: e.g. for LIDARSIM_PROFILE=cpu)")
    ("train-only", "only the training rows (with --no-torch: e.g. for LIDARSIM_PROFILE=cpu)")
    ("batch", "only the rows of this batch size (0: all)", cxxopts::value<int>()->default_value("0"))
    ("gemm", "size of the GEMM peak line (0 = skip)", cxxopts::value<int>()->default_value("4096"))
    ("kernels", "our model's kernel choices: rule (the fixed rules) or calibrated (measured on this CPU, cached; "
     "the warm-up runs take the calibration)", cxxopts::value<std::string>()->default_value("rule"))
    ("json", "also write the results as JSON to this file", cxxopts::value<std::string>())
    ("h,help", "show help");
  const auto opt = options.parse(argc, argv);
  if (opt.count("help")) {
    std::cout << options.help() << "\n";
    return std::nullopt;
  }
  BenchOptions o;
  o.reps = opt["reps"].as<int>();
  o.kernels = parse_plan_mode(opt["kernels"].as<std::string>(), "bench_unet_vs_torch: --kernels");
  o.warmup = opt["warmup"].as<int>();
  o.threads = opt["threads"].as<int>();
  o.rows = opt["rows"].as<int>();
  o.cols = opt["cols"].as<int>();
  o.lambda = opt["lambda"].as<float>();
  o.gemm_n = opt["gemm"].as<int>();
  o.only_batch = opt["batch"].as<int>();
  o.python = opt["python"].as<std::string>();
  o.torch_script = opt["torch-script"].as<std::string>();
  o.torch_settings = opt["torch-settings"].as<std::string>();
  if (opt.count("json")) o.json = opt["json"].as<std::string>();
  o.with_torch = !opt.count("no-torch");
  o.want_bf16 = !opt.count("no-bf16");
  o.infer_only = opt.count("infer-only") > 0;
  o.bf16_only = opt.count("bf16-only") > 0;
  o.train_only = opt.count("train-only") > 0;
  if (o.reps < 1) throw Error("--reps: expected >= 1");
  if (o.warmup < 0) throw Error("--warmup: expected >= 0");
  if (o.threads < 1) throw Error("--threads: expected >= 1");
  if (o.rows < 16 || o.cols < 16) throw Error("--rows/--cols: expected >= 16 (depth 4 halves four times)");
  std::stringstream list(opt["torch-wait-policies"].as<std::string>());
  for (std::string p; std::getline(list, p, ',');) {
    if (p != "passive" && p != "active")
      throw Error("--torch-wait-policies: expected passive and/or active, got \"" + p + "\"");
    o.wait_policies.push_back(p);
  }
  if (o.wait_policies.empty()) throw Error("--torch-wait-policies: no policy given");
  return o;
}

struct Row {
  std::string name;
  int batch;
  bool train;
  bool bf16 = false;  // our bf16 inference; the peer row is PyTorch's fp32 inference
  Timing ours, torch, torch_bf16;
};

// The rows the options ask for; bf16 rows only where the CPU has AVX-512 BF16.
std::vector<Row> select_rows(const BenchOptions& o, bool bf16) {
  std::vector<Row> table{{"train_b1", 1, true, false, {}, {}, {}},
                         {"train_b4", 4, true, false, {}, {}, {}},
                         {"infer_b1", 1, false, false, {}, {}, {}},
                         {"infer_b4", 4, false, false, {}, {}, {}}};
  if (bf16) {
    table.push_back({"infer_b1_bf16", 1, false, true, {}, {}, {}});
    table.push_back({"infer_b4_bf16", 4, false, true, {}, {}, {}});
  }
  auto drop = [&table](auto pred) { table.erase(std::remove_if(table.begin(), table.end(), pred), table.end()); };
  if (o.infer_only) drop([](const Row& r) { return r.train; });
  if (o.bf16_only) drop([](const Row& r) { return !r.bf16; });
  if (o.train_only) drop([](const Row& r) { return !r.train; });
  if (o.only_batch > 0) drop([&o](const Row& r) { return r.batch != o.only_batch; });
  return table;
}

void time_ours(std::vector<Row>& table, UNet& model, const UNetConfig& cfg, const BenchOptions& o) {
  OptimizerConfig oc;
  oc.kind = nn::OptimizerKind::Adam;
  Optimizer adam(oc, model.params().size());
  for (Row& row : table) {
    set_inference_precision(row.bf16 ? InferencePrecision::bf16 : InferencePrecision::fp32);
    const Batch b = make_batch(row.batch, cfg.in_channels, o.rows, o.cols, static_cast<std::uint32_t>(row.batch));
    Tensor y, dy;
    if (row.train) {
      row.ours = time_it(
          [&] {
            model.params().zero_grads();
            model.forward(b.x, y);
            dy.resize(y.shape());
            masked_mse(y, b.target, b.mask, &dy);
            l2_penalty(model.params(), o.lambda, true);
            model.backward(dy);
            adam.step(model.params());
          },
          o.warmup, o.reps);
    } else {
      row.ours = time_it([&] { model.predict(b.x, y); }, o.warmup, o.reps);
    }
    std::cerr << "bench: ours " << row.name << " " << row.ours.median << " s\n";
  }
  set_inference_precision(InferencePrecision::fp32);
}

// One peer run per wait policy; per row the fastest run's median, minimum and setting, the
// setting tagged with its policy (CPU time: the lowest, as across the script's settings).
nlohmann::json run_torch_policies(const BenchOptions& o, bool bf16) {
  const char* rows_of_peer[] = {"train_b1", "train_b4", "infer_b1", "infer_b4", "infer_b1_bf16", "infer_b4_bf16"};
  nlohmann::json peer;
  for (const std::string& policy : o.wait_policies) {
    nlohmann::json run = run_torch(o.python, o.torch_script, o.threads, o.rows, o.cols, o.reps, o.warmup, o.lambda,
                                   o.torch_settings, bf16, policy);
    for (const std::string k : rows_of_peer)
      if (run.contains(k + "_setting") && run[k + "_setting"].is_string())
        run[k + "_setting"] = run[k + "_setting"].get<std::string>() + ", " + policy;
    if (peer.is_null()) {
      peer = run;
      continue;
    }
    for (const std::string k : rows_of_peer) {
      if (!run.contains(k) || !run[k].is_number()) continue;
      const bool faster = !peer.contains(k) || !peer[k].is_number() || run[k].get<double>() < peer[k].get<double>();
      double cpu = run.value(k + "_cpu", 0.0);
      if (peer.contains(k + "_cpu") && peer[k + "_cpu"].is_number()) cpu = std::min(cpu, peer[k + "_cpu"].get<double>());
      if (faster)
        for (const std::string& e : {k, k + "_min", k + "_setting"})
          if (run.contains(e)) peer[e] = run[e];
      peer[k + "_cpu"] = cpu;
    }
  }
  return peer;
}

void attach_peer(std::vector<Row>& table, const nlohmann::json& peer) {
  for (Row& row : table) {
    const std::string peer_row = row.bf16 ? row.name.substr(0, row.name.size() - 5) : row.name;  // fp32 peer
    row.torch = {peer.at(peer_row).get<double>(), peer.at(peer_row + "_min").get<double>(),
                 peer.at(peer_row + "_cpu").get<double>()};
    if (row.bf16 && peer.contains(row.name) && peer.at(row.name).is_number())
      row.torch_bf16 = {peer.at(row.name).get<double>(), peer.at(row.name + "_min").get<double>(),
                        peer.at(row.name + "_cpu").get<double>()};
  }
}

// Prints the table and returns its rows as JSON.
nlohmann::json print_table(const std::vector<Row>& table, const UNet& model, const BenchOptions& o) {
  std::printf("unet-ref (3 -> 1, base 16, depth 4) at %d x %d, %d threads, median of %d after %d warm-up\n", o.rows,
              o.cols, o.threads, o.reps, o.warmup);
  std::printf("%-13s %10s %10s %12s %12s %13s %12s %10s %10s %10s\n", "row", "ours (s)", "torch (s)", "ours/torch",
              "ours GFLOP/s", "torch GFLOP/s", "min ratio", "ours CPU", "torch CPU", "CPU ratio");
  nlohmann::json out_rows = nlohmann::json::array();
  for (const Row& row : table) {
    // A training step counts as 3 forward passes (forward, backward to inputs, to weights).
    const double flops = (row.train ? 3.0 : 1.0) * model.forward_flops(row.batch, o.rows, o.cols);
    const double ratio = o.with_torch ? row.ours.median / row.torch.median : 0;
    const double min_ratio = o.with_torch ? row.ours.min / row.torch.min : 0;
    const double cpu_ratio = o.with_torch ? row.ours.cpu / row.torch.cpu : 0;
    if (o.with_torch)
      std::printf("%-13s %10.4f %10.4f %12.3f %12.1f %13.1f %12.3f %10.4f %10.4f %10.3f\n", row.name.c_str(),
                  row.ours.median, row.torch.median, ratio, flops / row.ours.median * 1e-9,
                  flops / row.torch.median * 1e-9, min_ratio, row.ours.cpu, row.torch.cpu, cpu_ratio);
    else
      std::printf("%-13s %10.4f %10s %12s %12.1f %13s %12s %10.4f %10s %10s\n", row.name.c_str(), row.ours.median,
                  "-", "-", flops / row.ours.median * 1e-9, "-", "-", row.ours.cpu, "-", "-");
    out_rows.push_back({{"row", row.name}, {"ours_s", row.ours.median}, {"ours_min_s", row.ours.min},
                        {"torch_s", row.torch.median}, {"torch_min_s", row.torch.min}, {"ratio", ratio},
                        {"min_ratio", min_ratio}, {"ours_cpu_s", row.ours.cpu}, {"torch_cpu_s", row.torch.cpu},
                        {"cpu_ratio", cpu_ratio}, {"ours_gflops", flops / row.ours.median * 1e-9},
                        {"flops", flops}});
    if (row.bf16 && row.torch_bf16.median > 0) {
      out_rows.back()["torch_bf16_s"] = row.torch_bf16.median;
      out_rows.back()["torch_bf16_cpu_s"] = row.torch_bf16.cpu;
    }
  }
  return out_rows;
}

// PyTorch's own bf16 (autocast) beside ours: an extra peer, not the reference; and ours bf16
// against ours fp32.
void print_bf16_lines(const std::vector<Row>& table, bool with_torch) {
  for (const Row& row : table)
    if (row.bf16 && with_torch) {
      if (row.torch_bf16.median > 0)
        std::printf("%s: torch bf16 autocast %.4f s (CPU %.4f s); ours bf16 / torch bf16: %.3f wall, %.3f CPU\n",
                    row.name.c_str(), row.torch_bf16.median, row.torch_bf16.cpu, row.ours.median / row.torch_bf16.median,
                    row.ours.cpu / row.torch_bf16.cpu);
      else
        std::printf("%s: torch bf16 autocast did not run (see the peer's notes on stderr)\n", row.name.c_str());
    }
  for (const Row& row : table)
    if (row.bf16 && !row.train) {
      const std::string fp32 = row.name.substr(0, row.name.size() - 5);
      for (const Row& r32 : table)
        if (r32.name == fp32)
          std::printf("%s: ours bf16 / ours fp32: %.3f wall, %.3f CPU\n", row.name.c_str(),
                      row.ours.median / r32.ours.median, row.ours.cpu / r32.ours.cpu);
    }
}

void print_peer(const nlohmann::json& peer) {
  std::printf("torch %s, %d threads; fastest setting per row: train_b1 %s, train_b4 %s, infer_b1 %s, infer_b4 %s\n",
              peer.value("torch_version", std::string("?")).c_str(), peer.value("threads", 0),
              peer.value("train_b1_setting", std::string("?")).c_str(),
              peer.value("train_b4_setting", std::string("?")).c_str(),
              peer.value("infer_b1_setting", std::string("?")).c_str(),
              peer.value("infer_b4_setting", std::string("?")).c_str());
  std::string libs;
  for (const auto& l : peer["blas"]) libs += " " + l.get<std::string>();
  std::printf("torch BLAS libraries loaded:%s\n", libs.c_str());
  std::string ops;
  for (const auto& o : peer["conv_ops"]) ops += " " + o.get<std::string>();
  std::printf("torch convolution ops:%s\n", ops.c_str());
}

}  // namespace

int main(int argc, char** argv) {
  try {
    const std::optional<BenchOptions> parsed = parse_options(argc, argv);
    if (!parsed) return 0;
    const BenchOptions& o = *parsed;
    omp_set_num_threads(o.threads);
    const std::string load_before = loadavg();

    const UNetConfig cfg{3, 1, 16, 4};
    UNet model(cfg);
    model.init(1);
    model.set_kernel_plan(KernelPlan(o.kernels));
    const bool bf16 = o.want_bf16 && bf16_supported();
    if (o.want_bf16 && !bf16) std::cerr << "bench: this CPU has no AVX-512 BF16: no bf16 rows\n";
    std::vector<Row> table = select_rows(o, bf16);
    time_ours(table, model, cfg, o);
    nlohmann::json peer;
    if (o.with_torch) {
      peer = run_torch_policies(o, bf16);
      attach_peer(table, peer);
    }
    double gemm_s = 0;
    if (o.gemm_n > 0) gemm_s = gemm_seconds(o.gemm_n, o.threads, std::max(1, std::min(o.reps, 3)));
    const std::string load_after = loadavg();

    const nlohmann::json out_rows = print_table(table, model, o);
    print_bf16_lines(table, o.with_torch);
    if (o.gemm_n > 0) {
      const double gf = 2.0 * o.gemm_n * double(o.gemm_n) * o.gemm_n / gemm_s * 1e-9;
      std::printf("GEMM %d^3 fp32 (Eigen, %d threads over columns): %.3f s, %.1f GFLOP/s\n", o.gemm_n, o.threads,
                  gemm_s, gf);
    }
    std::printf("forward: %.3f GFLOP per image; kernels at level %s (bf16 rows on %s)\n",
                model.forward_flops(1, o.rows, o.cols) * 1e-9, to_string(active_isa()),
                isa_at_least(Isa::amx_bf16) ? "AMX" : "AVX-512 BF16");
    if (o.with_torch) print_peer(peer);
    std::printf("load average before / after: %s / %s (numbers are only meaningful on an idle machine)\n",
                load_before.c_str(), load_after.c_str());
    if (!o.json.empty()) {
      nlohmann::json j{{"rows", o.rows},         {"cols", o.cols},     {"threads", o.threads},
                       {"reps", o.reps},         {"warmup", o.warmup}, {"table", out_rows},
                       {"gemm_n", o.gemm_n},     {"gemm_s", gemm_s},   {"torch", peer},
                       {"loadavg_before", load_before}, {"loadavg_after", load_after}};
      write_file_atomically(o.json, j.dump(2) + "\n");
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
