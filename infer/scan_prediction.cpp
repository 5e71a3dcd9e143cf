#include "infer/scan_prediction.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>

#include <nlohmann/json.hpp>

#include "common/atomic_file.h"
#include "common/error.h"
#include "common/image.h"
#include "common/plot.h"
#include "common/progress.h"
#include "data/kitti_object.h"
#include "data/point_cloud_io.h"
#include "data/semantickitti.h"
#include "data/velodyne.h"
#include "infer/intensity_model.h"
#include "infer/intensity_spread_terms.h"
#include "pgm/materials.h"
#include "pgm/projection.h"

namespace lidarsim::infer {
namespace {

struct ScanInput {
  std::string id;
  std::vector<pgm::Point> points;
};

// Lists the scans to predict; points are read one scan at a time in the loop.
struct ScanSource {
  std::vector<data::ScanFiles> semantickitti;
  std::vector<data::KittiObjectFrame> kitti;
  std::size_t size() const { return semantickitti.size() + kitti.size(); }
  ScanInput read(std::size_t i) const {
    if (i < semantickitti.size()) {
      const auto& s = semantickitti[i];
      data::LabelledScan scan = data::read_semantickitti_scan(s);
      // As import says it: the network then sees these points as "unlabeled".
      if (scan.unknown_labels)
        std::fprintf(stderr, "note: %s: %zu labels outside the SemanticKITTI classes, predicted as unlabeled\n",
                     s.label->string().c_str(), static_cast<std::size_t>(scan.unknown_labels));
      return {s.sequence + "_" + s.id, std::move(scan.points)};
    }
    const auto& k = kitti[i - semantickitti.size()];
    return {"kitti_" + k.id, data::read_kitti_object_scan(k).points};
  }
};

ScanSource list_sources(const PredictOptions& o) {
  ScanSource source;
  const int given = o.semantickitti.has_value() + o.kitti_object.has_value() + o.scan.has_value();
  if (given != 1) throw Error("lidar-infer predict: give exactly one of --semantickitti, --kitti-object, --scan");
  if (o.semantickitti) {
    // The network reads the class channel: scans without labels would all be "unlabeled".
    for (auto& s : data::list_semantickitti(*o.semantickitti))
      if (s.label) source.semantickitti.push_back(std::move(s));
    if (source.semantickitti.empty())
      throw input_error(o.semantickitti->string(), "labels", "no scan with a .label file: the model needs classes");
  }
  if (o.kitti_object) source.kitti = data::list_kitti_object(*o.kitti_object);
  if (o.scan) {
    data::ScanFiles files;
    files.sequence = "scan";
    files.id = o.scan->stem().string();
    files.bin = *o.scan;
    files.label = o.label;
    source.semantickitti.push_back(files);
  }
  if (o.max_frames > 0) {
    if (source.semantickitti.size() > static_cast<std::size_t>(o.max_frames))
      source.semantickitti.resize(static_cast<std::size_t>(o.max_frames));
    const std::size_t left = static_cast<std::size_t>(o.max_frames) - source.semantickitti.size();
    if (source.kitti.size() > left) source.kitti.resize(left);
  }
  if (source.size() == 0) throw Error("lidar-infer predict: no scans found");
  return source;
}

}  // namespace

Image comparison_image(const pgm::PolarGridMap& pgm, const std::vector<float>& predicted, const std::string& title) {
  const int rows = pgm.rows(), cols = pgm.cols();
  const float* measured = pgm.channel("intensity");
  const float* mask = pgm.channel("mask");
  std::vector<std::uint8_t> valid(pgm.cells());
  std::vector<float> error(pgm.cells());
  for (std::size_t i = 0; i < pgm.cells(); ++i) {
    valid[i] = mask[i] > 0;
    error[i] = std::fabs(predicted[i] - measured[i]);
  }
  const int scale = std::max(1, 192 / std::max(1, rows));
  auto row = [&](const float* values, float hi, const char* caption, const char* hi_label) {
    return add_caption_band(scale_rows(field_to_image(values, valid.data(), cols, rows, 0.f, hi), scale), caption,
                            ColourKey{"0", hi_label}, TextStyle{});
  };
  const char* error_caption = "absolute error |predicted - measured|";
  const Image stacked = stack_vertically({row(measured, 1.f, "measured intensity", "1"),
                                          row(predicted.data(), 1.f, "predicted intensity", "1"),
                                          row(error.data(), 0.5f, error_caption, "0.5 or more")},
                                         4);
  return add_caption_band(stacked, title + "  (black: no return)", kHeaderStyle);
}

namespace {

// Error sums over every scan: the cells' |error| and error^2, and per class (sum |err|, cells).
struct ErrorSums {
  double abs_sum = 0, sq_sum = 0;
  std::map<int, std::pair<double, long>> class_abs;  // class id -> (sum |err|, cells)
};

// One scan's cell metrics (the grid is what the network sees and what training scored), added to sums.
ScanResult score_cells(const std::string& id, const pgm::PolarGridMap& grid, const std::vector<float>& predicted,
                       ErrorSums& sums) {
  const float* measured = grid.channel("intensity");
  const float* mask = grid.channel("mask");
  const float* cls = grid.channel("class");
  ScanResult result;
  result.id = id;
  double scan_abs = 0, scan_sq = 0;
  for (std::size_t c = 0; c < grid.cells(); ++c) {
    if (mask[c] <= 0) continue;
    const double e = predicted[c] - measured[c];
    scan_abs += std::fabs(e);
    scan_sq += e * e;
    ++result.cells;
    auto& entry = sums.class_abs[static_cast<int>(cls[c])];
    entry.first += std::fabs(e);
    ++entry.second;
  }
  sums.abs_sum += scan_abs;
  sums.sq_sum += scan_sq;
  result.mae = result.cells ? scan_abs / result.cells : 0;
  result.rmse = result.cells ? std::sqrt(scan_sq / result.cells) : 0;
  return result;
}

// The scan's points with their cell's prediction and its error, as a point cloud file.
void write_predicted_cloud(const std::filesystem::path& path, const ScanInput& scan,
                           const std::vector<float>& point_prediction) {
  data::PointCloud cloud;
  std::vector<float> x, y, z, intensity, pred, err, klass;
  for (std::size_t p = 0; p < scan.points.size(); ++p) {
    const auto& pt = scan.points[p];
    x.push_back(pt.x);
    y.push_back(pt.y);
    z.push_back(pt.z);
    intensity.push_back(pt.intensity);
    pred.push_back(point_prediction[p]);
    err.push_back(std::isfinite(point_prediction[p]) ? std::fabs(point_prediction[p] - pt.intensity) : NAN);
    klass.push_back(static_cast<float>(pt.class_id));
  }
  cloud.add_field("x", std::move(x));
  cloud.add_field("y", std::move(y));
  cloud.add_field("z", std::move(z));
  cloud.add_field("intensity", std::move(intensity));
  cloud.add_field("predicted_intensity", std::move(pred));
  cloud.add_field("abs_error", std::move(err));
  cloud.add_field("class", std::move(klass));
  data::write_point_cloud(path, cloud);
}

void write_summary_json(const PredictOptions& o, const PredictSummary& summary) {
  nlohmann::json j;
  j["model"] = o.model.string();
  j["mae"] = summary.mae;
  j["rmse"] = summary.rmse;
  j["cells"] = summary.cells;
  j["seconds_per_scan"] = summary.seconds_per_scan;
  if (!summary.kernel_plan.empty()) j["kernel_plan"] = nlohmann::json::parse(summary.kernel_plan);
  for (const auto& s : summary.scans)
    j["scans"].push_back({{"id", s.id}, {"mae", s.mae}, {"rmse", s.rmse}, {"cells", s.cells},
                          {"cloud", s.cloud.filename().string()}, {"image", s.image.filename().string()}});
  for (const auto& c : summary.per_class) j["per_class"].push_back({{"class", c.name}, {"mae", c.mae}, {"cells", c.cells}});
  write_file_atomically(o.out / "summary.json", j.dump(2) + "\n");
}

void write_summary_md(const PredictOptions& o, const PredictSummary& summary) {
  std::string md = "# Intensity prediction\n\nModel: `" + o.model.string() + "`. Metrics over grid cells with a return.\n\n";
  char line[256];
  std::snprintf(line, sizeof line, "Overall: MAE %.4f, RMSE %.4f over %ld cells; %.3f s per scan (projection + UNet).\n\n",
                summary.mae, summary.rmse, summary.cells, summary.seconds_per_scan);
  md += line;
  md += "| scan | MAE | RMSE | cells |\n|---|---|---|---|\n";
  for (const auto& s : summary.scans) {
    std::snprintf(line, sizeof line, "| %s | %.4f | %.4f | %ld |\n", s.id.c_str(), s.mae, s.rmse, s.cells);
    md += line;
  }
  md += "\n| class | MAE | cells |\n|---|---|---|\n";
  for (const auto& c : summary.per_class) {
    std::snprintf(line, sizeof line, "| %s | %.4f | %ld |\n", c.name.c_str(), c.mae, c.cells);
    md += line;
  }
  md += "\n";
  for (const auto& s : summary.scans) md += "![" + s.id + "](" + s.image.filename().string() + ")\n";
  write_file_atomically(o.out / "summary.md", md);
}

}  // namespace

PredictSummary predict_scans(const PredictOptions& o) {
  if (o.format != "pcd" && o.format != "ply") throw Error("lidar-infer predict: --format must be pcd or ply");
  IntensityModel model = IntensityModel::load(o.model);
  model.set_kernel_mode(o.kernels);
  if (o.sample_intensity) model.sample_from_spread({o.seed}, "lidar-infer predict: --sample-intensity");
  if (!o.spread_terms.empty()) {
    if (!o.sample_intensity) throw Error("lidar-infer predict: --spread-terms needs --sample-intensity (the mean has no spread)");
    model.set_spread_terms(load_intensity_spread_terms(o.spread_terms).terms);
  }
  const ScanSource source = list_sources(o);
  std::filesystem::create_directories(o.out);

  PredictSummary summary;
  ErrorSums sums;
  double compute_seconds = 0;
  ProgressBar bar("predict", static_cast<long>(source.size()), o.progress);
  std::vector<float> predicted;
  pgm::ProjectOptions project_options;
  project_options.extra_channels = model.extra_channels();
  for (std::size_t i = 0; i < source.size(); ++i) {
    const ScanInput scan = source.read(i);
    const auto t0 = std::chrono::steady_clock::now();
    const pgm::ProjectionResult projected = pgm::project(scan.points, model.layout(), project_options, scan.id);
    const double calibrating = model.kernel_plan().calibration_seconds();
    model.predict(projected.pgm, predicted, i);
    // A first run on this CPU measures its kernels here (nn/kernel_plan.h): not the scan's cost.
    compute_seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() -
                       (model.kernel_plan().calibration_seconds() - calibrating);
    ScanResult result = score_cells(scan.id, projected.pgm, predicted, sums);
    summary.cells += result.cells;
    // Every point gets its cell's prediction.
    result.cloud = o.out / (scan.id + "." + o.format);
    write_predicted_cloud(result.cloud, scan, pgm::back_project(predicted.data(), projected.point_cell));
    result.image = o.out / (scan.id + "_intensity.png");
    char title[128];
    std::snprintf(title, sizeof title, "scan %s  MAE %.4f", scan.id.c_str(), result.mae);
    write_png(result.image, comparison_image(projected.pgm, predicted, title));
    summary.scans.push_back(result);
    char status[64];
    std::snprintf(status, sizeof status, "MAE %.4f", result.mae);
    bar.update(static_cast<long>(i + 1), status);
  }
  bar.finish();
  summary.mae = summary.cells ? sums.abs_sum / summary.cells : 0;
  summary.rmse = summary.cells ? std::sqrt(sums.sq_sum / summary.cells) : 0;
  summary.seconds_per_scan = compute_seconds / static_cast<double>(source.size());
  for (const auto& [id, entry] : sums.class_abs)
    summary.per_class.push_back({pgm::class_name(id), entry.first / std::max(1L, entry.second), entry.second});
  summary.kernel_plan = model.kernel_plan().to_json();
  write_summary_json(o, summary);
  write_summary_md(o, summary);
  return summary;
}

}  // namespace lidarsim::infer
