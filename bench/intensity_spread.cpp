// Intensity as a distribution on held-out cells (docs/intensity.md "Intensity as a distribution"):
// for a checkpoint with a spread head, the histogram intersection of the measured intensity on the
// guarded split's held-out cells against (a) the mean prediction and (b) intensity drawn from the
// predicted distribution (infer/intensity_sampling.h, the seeds given), beside the real-vs-real
// ceiling computed as `lidar-qualify intensity` computes it (the held-out cells of alternate scans
// against each other, qualify/similarity.h). Same cells, same import, same split as that command.
//   bench_intensity_spread --model ck.h5 --semantickitti DIR [--seeds 1,2,3] [--spread-scale F] [--out spread.json]
// --spread-scale replaces the checkpoint's calibration factor of the spread (1: uncalibrated).
#include <cstdio>
#include <cxxopts.hpp>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "common/atomic_file.h"
#include "common/error.h"
#include "infer/intensity_model.h"
#include "nn/checkpoint.h"
#include "qualify/intensity.h"
#include "qualify/similarity.h"

using namespace lidarsim;

namespace {

// The model's per-cell output (mean, or a draw with `seed`) on the held-out cells, in c's order.
std::vector<double> held_out_prediction(infer::IntensityModel& model, const data::Dataset& ds,
                                        const qualify::IntensityCells& c) {
  const long cells = static_cast<long>(ds.rows()) * ds.cols();
  std::vector<std::vector<float>> frames(static_cast<std::size_t>(ds.size()));
  for (int n = 0; n < ds.size(); ++n) model.predict(ds.frame_pgm(n), frames[static_cast<std::size_t>(n)], n);
  std::vector<double> out;
  for (std::size_t i = 0; i < c.size(); ++i)
    if (c.held_out[i]) out.push_back(frames[static_cast<std::size_t>(c.frame[i])][static_cast<std::size_t>(c.cell[i] % cells)]);
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  cxxopts::Options options("bench_intensity_spread", "held-out intensity histograms: mean vs sampled vs measured");
  options.add_options()("model", "checkpoint with a spread head", cxxopts::value<std::string>())(
      "semantickitti", "SemanticKITTI folder", cxxopts::value<std::string>())(
      "seeds", "sampling seeds", cxxopts::value<std::string>()->default_value("1,2,3"))(
      "spread-scale", "replace the checkpoint's spread calibration factor (1: uncalibrated)", cxxopts::value<float>())(
      "out", "JSON report", cxxopts::value<std::string>()->default_value(""));
  try {
    const auto args = options.parse(argc, argv);
    if (!args.count("model") || !args.count("semantickitti")) {
      std::cout << options.help() << "\n";
      return 2;
    }
    const std::string checkpoint = args["model"].as<std::string>();
    infer::IntensityModel model = infer::IntensityModel::load(checkpoint);
    const data::Dataset ds = qualify::import_for_qualify(args["semantickitti"].as<std::string>(), model.extra_channels());
    const int depth = nn::read_checkpoint_meta(checkpoint).unet.depth;
    const data::SectorSplit split = qualify::intensity_split(ds, "guarded", depth);
    const qualify::IntensityCells c = qualify::intensity_cells(ds, split);
    std::vector<double> measured;
    std::vector<std::vector<double>> by_scan(static_cast<std::size_t>(ds.size()));
    for (std::size_t i = 0; i < c.size(); ++i)
      if (c.held_out[i]) {
        measured.push_back(c.measured[i]);
        by_scan[static_cast<std::size_t>(c.frame[i])].push_back(c.measured[i]);
      }
    const double ceiling = qualify::real_vs_real_ceiling(by_scan);
    const std::vector<double> mean = held_out_prediction(model, ds, c);
    double mae = 0;
    for (std::size_t i = 0; i < mean.size(); ++i) mae += std::abs(mean[i] - measured[i]);
    mae /= std::max<std::size_t>(1, mean.size());
    const qualify::Similarity sm = qualify::compare(mean, measured);
    nlohmann::json j = {{"checkpoint", checkpoint}, {"split", split.describe(ds.cols())}, {"cells", measured.size()},
                        {"ceiling", ceiling}, {"mean", {{"mae", mae}, {"intersection", sm.intersection},
                                                        {"interval", {sm.interval.lo, sm.interval.hi}}}}};
    std::printf("held-out cells %zu; ceiling (alternate scans) %.3f\nmean:    MAE %.4f  intersection %.3f [%.3f, %.3f]  = %.3f x ceiling\n",
                measured.size(), ceiling, mae, sm.intersection, sm.interval.lo, sm.interval.hi, sm.intersection / ceiling);
    if (model.spread()) {
      const float factor = args.count("spread-scale") ? args["spread-scale"].as<float>()
                                                      : nn::read_checkpoint_meta(checkpoint).unet.spread_scale;
      j["spread_scale"] = factor;
      std::printf("spread scale factor %.4f (%s)\n", factor, args.count("spread-scale") ? "--spread-scale" : "the checkpoint's");
      std::string seeds = args["seeds"].as<std::string>();
      for (std::size_t start = 0; start < seeds.size();) {
        const std::size_t comma = std::min(seeds.find(',', start), seeds.size());
        const std::uint64_t seed = std::stoull(seeds.substr(start, comma - start));
        start = comma + 1;
        model.sample_from_spread({seed, 0.f, 1.f}, "bench_intensity_spread --spread-scale",
                                 args.count("spread-scale") ? std::optional(args["spread-scale"].as<float>()) : std::nullopt);
        const std::vector<double> drawn = held_out_prediction(model, ds, c);
        double dmae = 0;
        for (std::size_t i = 0; i < drawn.size(); ++i) dmae += std::abs(drawn[i] - measured[i]);
        dmae /= std::max<std::size_t>(1, drawn.size());
        const qualify::Similarity ss = qualify::compare(drawn, measured);
        j["sampled"].push_back({{"seed", seed}, {"mae", dmae}, {"intersection", ss.intersection},
                                {"interval", {ss.interval.lo, ss.interval.hi}}});
        std::printf("sampled (seed %llu): MAE %.4f  intersection %.3f [%.3f, %.3f]  = %.3f x ceiling\n",
                    static_cast<unsigned long long>(seed), dmae, ss.intersection, ss.interval.lo, ss.interval.hi,
                    ss.intersection / ceiling);
      }
    }
    if (!args["out"].as<std::string>().empty()) write_file_atomically(args["out"].as<std::string>(), j.dump(2));
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
