// The bf16 inference path's accuracy gate (the path is used only while the validation MAE moves
// by less than 0.0005): a checkpoint scored as `lidar-qualify intensity` scores it (held-out
// cells of the guarded split of the scans in --semantickitti), once in fp32 and once in bf16,
// on the same cells in one run. Prints both MAEs, their difference, the largest |bf16 - fp32|
// prediction over the held-out cells and over every cell, and the process CPU time per scan.
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <cxxopts.hpp>
#include <string>
#include <vector>

#include "common/error.h"
#include "data/split.h"
#include "infer/intensity_model.h"
#include "nn/checkpoint.h"
#include "nn/cpu_features.h"
#include "nn/precision.h"
#include "qualify/intensity/intensity.h"

#ifndef LIDARSIM_SOURCE_DIR
#define LIDARSIM_SOURCE_DIR "."
#endif

using namespace lidarsim;

namespace {

double cpu_seconds() {
  timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return t.tv_sec + 1e-9 * t.tv_nsec;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    cxxopts::Options options("bench_bf16_accuracy", "validation MAE of a checkpoint in fp32 and in bf16, same cells");
    options.add_options()
      ("model", "checkpoint", cxxopts::value<std::string>()->default_value(LIDARSIM_SOURCE_DIR "/data/models/intensity_unet.h5"))
      ("semantickitti", "SemanticKITTI folder (as for lidar-qualify intensity)", cxxopts::value<std::string>())
      ("threads", "OpenMP threads", cxxopts::value<int>()->default_value("2"))
      ("h,help", "show help");
    const auto opt = options.parse(argc, argv);
    if (opt.count("help") || !opt.count("semantickitti")) {
      std::printf("%s\n", options.help().c_str());
      return opt.count("help") ? 0 : 2;
    }
    if (!nn::bf16_supported()) throw Error("bench_bf16_accuracy: this CPU has no AVX-512 BF16");
    omp_set_num_threads(opt["threads"].as<int>());
    const std::string model_path = opt["model"].as<std::string>();
    infer::IntensityModel model = infer::IntensityModel::load(model_path);
    const data::Dataset ds = qualify::import_for_qualify(opt["semantickitti"].as<std::string>(), model.extra_channels());
    const int depth = nn::read_checkpoint_meta(model_path).unet.depth;
    const data::SectorSplit split = qualify::intensity_split(ds, "guarded", depth);
    const qualify::IntensityCells c = qualify::intensity_cells(ds, split);
    const int cells = ds.rows() * ds.cols();

    std::vector<std::vector<float>> frames[2];
    double mae[2] = {0, 0}, cpu[2] = {0, 0};
    long held = 0;
    for (int p = 0; p < 2; ++p) {
      nn::set_inference_precision(p ? nn::InferencePrecision::bf16 : nn::InferencePrecision::fp32);
      std::vector<float> out;
      model.predict(ds.frame_pgm(0), out);  // warm-up: buffers grow here
      frames[p].resize(ds.size());
      const double t0 = cpu_seconds();
      for (int n = 0; n < ds.size(); ++n) {
        model.predict(ds.frame_pgm(n), out);
        frames[p][n] = out;
      }
      cpu[p] = (cpu_seconds() - t0) / ds.size();
      held = 0;
      for (std::size_t i = 0; i < c.size(); ++i)
        if (c.held_out[i]) mae[p] += std::abs(frames[p][c.frame[i]][c.cell[i] % cells] - c.measured[i]), ++held;
      mae[p] /= std::max(held, 1L);
    }
    double max_held = 0, max_all = 0, sum_all = 0;
    for (std::size_t i = 0; i < c.size(); ++i)
      if (c.held_out[i]) {
        const long k = c.cell[i] % cells;
        max_held = std::max(max_held, static_cast<double>(std::abs(frames[1][c.frame[i]][k] - frames[0][c.frame[i]][k])));
      }
    long all = 0;
    for (int n = 0; n < ds.size(); ++n)
      for (int k = 0; k < cells; ++k) {
        const double d = std::abs(frames[1][n][k] - frames[0][n][k]);
        max_all = std::max(max_all, d), sum_all += d, ++all;
      }
    const double delta = mae[1] - mae[0];
    std::printf("%s on %d scans, %ld held-out cells (guarded split, as lidar-qualify intensity)\n", model_path.c_str(),
                ds.size(), held);
    std::printf("validation MAE fp32 %.6f  bf16 %.6f  difference %+.6f (gate: |difference| < 0.0005: %s)\n", mae[0],
                mae[1], delta, std::abs(delta) < 5e-4 ? "pass" : "FAIL");
    std::printf("|bf16 - fp32| prediction: max %.2e over held-out cells, max %.2e and mean %.2e over all %ld cells\n",
                max_held, max_all, sum_all / std::max(all, 1L), all);
    std::printf("process CPU time per scan: fp32 %.4f s, bf16 %.4f s (%.2fx); bf16 on %s (level %s)\n", cpu[0],
                cpu[1], cpu[0] / cpu[1], nn::isa_at_least(nn::Isa::amx_bf16) ? "AMX" : "AVX-512 BF16",
                nn::to_string(nn::active_isa()));
    return std::abs(delta) < 5e-4 ? 0 : 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
