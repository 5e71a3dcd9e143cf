// Intensity as a distribution on held-out cells (docs/intensity.md "Intensity as a distribution"):
// for a checkpoint with a spread head, the histogram intersection of the measured intensity on the
// guarded split's held-out cells against (a) the mean prediction and (b) intensity drawn from the
// predicted distribution (infer/intensity_sampling.h, the seeds given), beside the real-vs-real
// ceiling computed as `lidar-qualify intensity` computes it (the held-out cells of alternate scans
// against each other, qualify/similarity.h). Same cells, same import, same split as that command.
//   bench_intensity_spread --model ck.h5 --semantickitti DIR [--seeds 1,2,3] [--spread-scale F] [--parametric]
//                          [--refit-residual new.h5] [--diagnose] [--dump-cells cells.csv] [--out spread.json]
// --spread-scale replaces the checkpoint's calibration factor of the spread (1: uncalibrated);
// --parametric draws from the head's Laplace/Gaussian even when the checkpoint has a residual table;
// --refit-residual gives a checkpoint of the builds before the table one (fitted as lidar-train
// --early-stop fits it, on the inner region) and measures that; --diagnose prints where the
// histograms differ.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <cxxopts.hpp>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "common/atomic_file.h"
#include "common/error.h"
#include "infer/intensity_model.h"
#include "data/frame_source.h"
#include "data/split.h"
#include "nn/checkpoint.h"
#include "nn/receptive_field.h"
#include "pgm/materials.h"
#include "qualify/intensity/intensity.h"
#include "qualify/similarity.h"
#include "train/spread_metrics.h"

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


// Per held-out cell: the predicted mean and scale (the spread head's, with the factor in use).
void held_out_distribution(infer::IntensityModel& model, const data::Dataset& ds, const qualify::IntensityCells& c,
                           std::vector<double>& mean, std::vector<double>& scale) {
  const long cells = static_cast<long>(ds.rows()) * ds.cols();
  std::vector<std::vector<float>> m(static_cast<std::size_t>(ds.size())), b(m.size());
  for (int n = 0; n < ds.size(); ++n)
    model.predict_distribution(ds.frame_pgm(n), m[static_cast<std::size_t>(n)], b[static_cast<std::size_t>(n)]);
  for (std::size_t i = 0; i < c.size(); ++i)
    if (c.held_out[i]) {
      const auto f = static_cast<std::size_t>(c.frame[i]);
      mean.push_back(m[f][static_cast<std::size_t>(c.cell[i] % cells)]);
      scale.push_back(b[f][static_cast<std::size_t>(c.cell[i] % cells)]);
    }
}

double quantile(std::vector<double> v, double p) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[static_cast<std::size_t>(p * (v.size() - 1))];
}

// Where the histograms differ: measured, mean and one draw on the measured values' bins; what sits
// at the clamp bounds; what the 0.01 grid of the measured values does to the intersection; the
// standardised residual's quantiles against the Laplace's; per class, scale calibration and
// intersections. `cls` is the class of each held-out cell (in order).
void print_diagnosis(const std::vector<double>& measured, const std::vector<double>& mean,
                     const std::vector<double>& scale, const std::vector<double>& drawn, const std::vector<int>& cls) {
  const qualify::SharedBins bins = qualify::shared_bins(measured, measured);
  const auto hm = qualify::histogram(measured, bins), hp = qualify::histogram(mean, bins),
             hd = qualify::histogram(drawn, bins);
  const double w = (bins.hi - bins.lo) / bins.bins;
  std::printf("\nhistograms on the measured 1st-99th percentile bins [%.4f, %.4f), width %.4f:\n", bins.lo, bins.hi, w);
  std::printf("  bin from   measured  mean    sampled\n");
  for (int k = 0; k < bins.bins + 2; ++k)
    std::printf("  %8s  %.4f    %.4f  %.4f\n",
                k == 0 ? "below" : k == bins.bins + 1 ? "above" : std::to_string(bins.lo + (k - 1) * w).substr(0, 6).c_str(),
                hm[static_cast<std::size_t>(k)], hp[static_cast<std::size_t>(k)], hd[static_cast<std::size_t>(k)]);
  const auto share = [](const std::vector<double>& v, auto pred) {
    return static_cast<double>(std::count_if(v.begin(), v.end(), pred)) / std::max<std::size_t>(1, v.size());
  };
  std::printf("at 0: measured %.4f, mean %.4f, sampled %.4f; at 1: measured %.4f, sampled %.4f\n",
              share(measured, [](double x) { return x <= 0; }), share(mean, [](double x) { return x <= 0; }),
              share(drawn, [](double x) { return x <= 0; }), share(measured, [](double x) { return x >= 1; }),
              share(drawn, [](double x) { return x >= 1; }));
  // The measured values sit on a grid (KITTI: 0.01); a continuous sample cannot fill a 40-bin
  // histogram the way a grid does. Measured + uniform jitter within its grid step is what a perfect
  // continuous sampler scores; the draw rounded to the grid is the sampler made to report like the sensor.
  std::vector<double> sorted = measured;
  std::sort(sorted.begin(), sorted.end());
  double step = 1;
  for (std::size_t i = 1; i < sorted.size(); ++i)
    if (sorted[i] - sorted[i - 1] > 1e-6) step = std::min(step, sorted[i] - sorted[i - 1]);
  std::vector<double> jittered = measured, rounded = drawn;
  for (std::size_t i = 0; i < jittered.size(); ++i) {
    double u1 = 0, u2 = 0;
    infer::cell_uniforms(99, 0, i, u1, u2);
    jittered[i] += (u1 - 0.5) * step;
    rounded[i] = std::round(rounded[i] / step) * step;
  }
  std::printf("measured grid step %.4f: measured vs itself jittered within the step %.3f; sampled rounded to it %.3f\n",
              step, qualify::histogram_intersection(jittered, measured), qualify::histogram_intersection(rounded, measured));
  std::vector<double> z(measured.size());
  for (std::size_t i = 0; i < z.size(); ++i) z[i] = (measured[i] - mean[i]) / std::max(scale[i], 1e-6);
  std::printf("standardised residual (y - mean) / scale, quantile: held-out | Laplace(0, 1)\n");
  for (double p : {0.01, 0.05, 0.1, 0.25, 0.5, 0.75, 0.9, 0.95, 0.99})
    std::printf("  %.2f  %+.3f | %+.3f\n", p, quantile(z, p), p < 0.5 ? std::log(2 * p) : -std::log(2 - 2 * p));
  std::map<int, std::vector<std::size_t>> by_class;
  for (std::size_t i = 0; i < cls.size(); ++i) by_class[cls[i]].push_back(i);
  std::printf("per class (>= 300 cells): cells, mean |y - mean| / scale (1: calibrated Laplace), mean MAE, "
              "intersection mean / sampled, median scale\n");
  for (const auto& [k, idx] : by_class) {
    if (idx.size() < 300) continue;
    std::vector<double> m, p, d, b;
    double ratio = 0, mae = 0;
    for (std::size_t i : idx) {
      m.push_back(measured[i]), p.push_back(mean[i]), d.push_back(drawn[i]), b.push_back(scale[i]);
      ratio += std::abs(z[i]), mae += std::abs(measured[i] - mean[i]);
    }
    std::printf("  %-16s %6zu  %.3f  %.4f  %.3f / %.3f  %.4f\n", pgm::class_name(k).c_str(), idx.size(),
                ratio / idx.size(), mae / idx.size(), qualify::histogram_intersection(p, m),
                qualify::histogram_intersection(d, m), quantile(b, 0.5));
  }
}

// Every cell with a return outside the guard bands as CSV (frame, column, row, class, range,
// measured, mean, scale, held_out), for analyses outside the project.
void dump_cells(infer::IntensityModel& model, const data::Dataset& ds, const qualify::IntensityCells& c,
                const std::string& path) {
  const long cells = static_cast<long>(ds.rows()) * ds.cols();
  std::vector<std::vector<float>> m(static_cast<std::size_t>(ds.size())), b(m.size());
  for (int n = 0; n < ds.size(); ++n)
    model.predict_distribution(ds.frame_pgm(n), m[static_cast<std::size_t>(n)], b[static_cast<std::size_t>(n)]);
  std::string text = "frame,col,row,class,range,measured,mean,scale,held_out\n";
  char line[256];
  for (std::size_t i = 0; i < c.size(); ++i) {
    const auto f = static_cast<std::size_t>(c.frame[i]);
    const auto at = static_cast<std::size_t>(c.cell[i] % cells);
    std::snprintf(line, sizeof line, "%d,%ld,%d,%d,%.3f,%.4f,%.6f,%.6f,%d\n", c.frame[i], c.cell[i] % ds.cols(), c.row[i],
                  c.cls[i], c.feature[0][i], c.measured[i], m[f][at], b[f][at], c.held_out[i] ? 1 : 0);
    text += line;
  }
  write_file_atomically(path, text);
}

// A checkpoint written before the residual table existed, given one as lidar-train --early-stop
// now fits it: on the inner region lidar-train carves out of the guarded split's training columns
// (data/split.h inner_split, 32 columns) with the checkpoint's scale factor; saved to `out`.
void refit_residual(const std::string& checkpoint, const std::string& out, const data::Dataset& ds,
                    const data::SectorSplit& split) {
  nn::Checkpoint meta = nn::read_checkpoint_meta(checkpoint);
  nn::UNet model(meta.unet);
  nn::load_checkpoint(checkpoint, model, nullptr);
  const infer::IntensityModel loaded = infer::IntensityModel::load(checkpoint);
  const data::SectorSplit inner = data::inner_split(split, nn::receptive_field_half_width(meta.unet), ds.cols(), 32);
  const auto source = data::memory_frame_source(ds, "bench");
  const nn::SpreadResidual r = train::fit_spread_residual(model, loaded.encoder(), {source.get()}, inner);
  std::printf("refit: inner region %s: %d quantiles x %d bins of the mean, grid step %g -> %s\n",
              inner.describe(ds.cols()).c_str(), r.levels, r.bins(), r.target_step, out.c_str());
  nn::save_checkpoint(out, model, nullptr, meta);
}

// Draws the held-out cells once per seed and scores each draw against the measured values
// (MAE, histogram intersection); --diagnose prints the first draw's diagnosis.
void score_samples(infer::IntensityModel& model, const data::Dataset& ds, const qualify::IntensityCells& c,
                   const std::vector<double>& measured, const std::vector<int>& held_out_class, double ceiling,
                   const cxxopts::ParseResult& args, nlohmann::json& j) {
  std::string seeds = args["seeds"].as<std::string>();
  for (std::size_t start = 0; start < seeds.size();) {
    const std::size_t comma = std::min(seeds.find(',', start), seeds.size());
    const std::uint64_t seed = std::stoull(seeds.substr(start, comma - start));
    start = comma + 1;
    model.sample_from_spread({seed, 0.f, 1.f, args.count("parametric") > 0}, "bench_intensity_spread --spread-scale",
                             args.count("spread-scale") ? std::optional(args["spread-scale"].as<float>()) : std::nullopt);
    const std::vector<double> drawn = held_out_prediction(model, ds, c);
    double dmae = 0;
    for (std::size_t i = 0; i < drawn.size(); ++i) dmae += std::abs(drawn[i] - measured[i]);
    dmae /= std::max<std::size_t>(1, drawn.size());
    const qualify::Similarity ss = qualify::compare(drawn, measured);
    const auto zeros = [](const std::vector<double>& v) {
      return static_cast<double>(std::count(v.begin(), v.end(), 0.0)) / std::max<std::size_t>(1, v.size());
    };
    j["sampled"].push_back({{"seed", seed}, {"mae", dmae}, {"intersection", ss.intersection},
                            {"interval", {ss.interval.lo, ss.interval.hi}}, {"zeros", zeros(drawn)}});
    std::printf("sampled (seed %llu): MAE %.4f  intersection %.3f [%.3f, %.3f]  = %.3f x ceiling; zeros %.4f (measured %.4f)\n",
                static_cast<unsigned long long>(seed), dmae, ss.intersection, ss.interval.lo, ss.interval.hi,
                ss.intersection / ceiling, zeros(drawn), zeros(measured));
    if (args.count("diagnose") && j["sampled"].size() == 1) {
      std::vector<double> mu, b;
      held_out_distribution(model, ds, c, mu, b);
      print_diagnosis(measured, mu, b, drawn, held_out_class);
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  cxxopts::Options options("bench_intensity_spread", "held-out intensity histograms: mean vs sampled vs measured");
  options.add_options()("model", "checkpoint with a spread head", cxxopts::value<std::string>())(
      "semantickitti", "SemanticKITTI folder", cxxopts::value<std::string>())(
      "seeds", "sampling seeds", cxxopts::value<std::string>()->default_value("1,2,3"))(
      "refit-residual", "fit the residual table on the inner region (as lidar-train --early-stop), save the checkpoint here and use it",
      cxxopts::value<std::string>())(
      "parametric", "draw from the head's Laplace/Gaussian even with a residual table")(
      "spread-scale", "replace the checkpoint's spread calibration factor (1: uncalibrated)", cxxopts::value<float>())(
      "out", "JSON report", cxxopts::value<std::string>()->default_value(""))(
      "dump-cells", "CSV of every unguarded cell's measured value, mean and scale", cxxopts::value<std::string>())(
      "diagnose", "print the histograms, the standardised residual and per-class figures (first seed's draw)");
  try {
    const auto args = options.parse(argc, argv);
    if (!args.count("model") || !args.count("semantickitti")) {
      std::cout << options.help() << "\n";
      return 2;
    }
    std::string checkpoint = args["model"].as<std::string>();
    const data::Dataset ds = qualify::import_for_qualify(args["semantickitti"].as<std::string>(),
                                                         infer::IntensityModel::load(checkpoint).extra_channels());
    const int depth = nn::read_checkpoint_meta(checkpoint).unet.depth;
    const data::SectorSplit split = qualify::intensity_split(ds, "guarded", depth);
    if (args.count("refit-residual")) {
      refit_residual(checkpoint, args["refit-residual"].as<std::string>(), ds, split);
      checkpoint = args["refit-residual"].as<std::string>();
    }
    infer::IntensityModel model = infer::IntensityModel::load(checkpoint);
    const qualify::IntensityCells c = qualify::intensity_cells(ds, split);
    std::vector<double> measured;
    std::vector<int> held_out_class;
    std::vector<std::vector<double>> by_scan(static_cast<std::size_t>(ds.size()));
    for (std::size_t i = 0; i < c.size(); ++i)
      if (c.held_out[i]) {
        measured.push_back(c.measured[i]);
        held_out_class.push_back(c.cls[i]);
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
      score_samples(model, ds, c, measured, held_out_class, ceiling, args, j);
    }
    if (args.count("dump-cells")) dump_cells(model, ds, c, args["dump-cells"].as<std::string>());
    if (!args["out"].as<std::string>().empty()) write_file_atomically(args["out"].as<std::string>(), j.dump(2));
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
