#pragma once
// `lidar-infer predict`: intensity for recorded scans. Each scan is projected into a PGM as in
// training, the UNet predicts every cell, and every point gets the prediction of its cell. Per
// scan it writes a point cloud (x, y, z, intensity = measured, predicted, abs_error, class) and a
// PNG with three rows — measured / predicted / absolute error — like the paper's Figures 9-10;
// at the end summary.json and summary.md with MAE/RMSE overall and per class.
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "common/image.h"
#include "nn/kernel_plan.h"

namespace lidarsim::pgm {
class PolarGridMap;
}

namespace lidarsim::infer {

struct PredictOptions {
  std::filesystem::path model;
  std::optional<std::filesystem::path> semantickitti;  // folder as lidar-data import takes it
  std::optional<std::filesystem::path> kitti_object;
  std::optional<std::filesystem::path> scan;   // one .bin
  std::optional<std::filesystem::path> label;  // its .label (optional)
  std::filesystem::path out = "out/predict";
  std::string format = "pcd";  // or "ply"
  int max_frames = 0;          // 0 = all
  bool progress = true;
  // With a spread head: draw each cell's intensity from the predicted distribution (seeded; frame
  // = the scan's index) instead of the mean (infer/intensity_sampling.h).
  bool sample_intensity = false;
  std::uint64_t seed = 1;
  // Terms on the sampled spread (infer/intensity_spread_terms.h); needs sample_intensity.
  std::string spread_terms;
  // How the UNet's 3x3 kernels are chosen (nn/kernel_plan.h); the plan goes into summary.json.
  nn::PlanMode kernels = nn::PlanMode::rule;
};

struct ClassError {
  std::string name;
  double mae = 0;
  long cells = 0;
};

struct ScanResult {
  std::string id;
  double mae = 0, rmse = 0;  // over the grid cells with a return
  long cells = 0;
  std::filesystem::path cloud, image;
};

struct PredictSummary {
  std::vector<ScanResult> scans;
  std::vector<ClassError> per_class;
  double mae = 0, rmse = 0;
  long cells = 0;
  double seconds_per_scan = 0;  // projection + inference, outputs excluded
  std::string kernel_plan;      // the kernels the UNet took (nn::KernelPlan::to_json)
};

PredictSummary predict_scans(const PredictOptions& options);

// The per-scan picture: measured / predicted / |error| rows (one image row per beam, scaled to
// about 192 px), each under a caption with its colour scale, below a header band with `title`.
Image comparison_image(const pgm::PolarGridMap& pgm, const std::vector<float>& predicted, const std::string& title);

}  // namespace lidarsim::infer
