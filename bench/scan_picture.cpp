// A measured scan above its simulation from the same ideal geometry (issue 27, item 9):
//   bench_scan_picture [--data DIR] [--scan N] [--returns MODEL.json] [--out docs/measured_vs_simulated.png]
// The ideal geometry is pgm::return_target of the measured scan: its returns plus the drops at
// their estimated ranges and classes (sky stays empty). On it the simulation draws the return
// model (sensor/return_model.h), moves the ranges by the range-noise model (sensor/range_noise.h)
// and predicts intensity with the bundled UNet (infer/intensity_model.h), whose input channels
// come from projecting the ideal points exactly as lidar-infer predict projects a recorded scan.
// Four rows, each captioned: measured range, simulated range, measured intensity, simulated
// intensity (black: no return); a window of --columns columns centred on --centre-deg.
#include <cmath>
#include <cstdio>
#include <cxxopts.hpp>
#include <filesystem>
#include <string>
#include <vector>

#include "common/error.h"
#include "common/image.h"
#include "common/plot.h"
#include "data/semantickitti.h"
#include "infer/intensity_model.h"
#include "pgm/projection.h"
#include "pgm/return_target.h"
#include "sensor/range_noise.h"
#include "sensor/return_model.h"

using namespace lidarsim;
namespace fs = std::filesystem;

namespace {

void require_file(const fs::path& p, const std::string& what) {
  if (!fs::is_regular_file(p)) throw Error(p.string() + ": " + what + " not found");
}

// The measured points (each tagged with the row it was projected to) plus one point per drop
// cell at its estimated range along the cell's beam: a point cloud of the ideal geometry that
// pgm::project (RowMode::Ring) puts back into the same cells.
std::vector<pgm::Point> ideal_points(const std::vector<pgm::Point>& measured, const pgm::ProjectionResult& projected,
                                     const pgm::ReturnTarget& target, const pgm::BeamLayout& layout) {
  const int cols = projected.pgm.cols();
  std::vector<pgm::Point> out;
  for (std::size_t i = 0; i < measured.size(); ++i) {
    if (projected.point_cell[i] < 0) continue;
    pgm::Point p = measured[i];
    p.ring = static_cast<int>(projected.point_cell[i] / cols);
    out.push_back(p);
  }
  for (int row = 0; row < target.rows; ++row)
    for (int col = 0; col < target.cols; ++col) {
      const std::size_t cell = static_cast<std::size_t>(row) * cols + col;
      if (target.label[cell] != pgm::ReturnLabel::Drop) continue;
      const double r = target.range[cell], el = layout.elevations_rad[row];
      const double az = layout.azimuth_of_column(col) + layout.azimuth_offset(row);
      pgm::Point p;
      p.x = static_cast<float>(r * std::cos(el) * std::cos(az));
      p.y = static_cast<float>(r * std::cos(el) * std::sin(az));
      p.z = static_cast<float>(r * std::sin(el));
      p.class_id = target.class_id[cell];
      p.ring = row;
      out.push_back(p);
    }
  return out;
}

// Columns [c0, c0 + n) of a field (wrapping around) with its validity.
void window(const float* values, const float* mask, int rows, int cols, int c0, int n, std::vector<float>& v,
            std::vector<std::uint8_t>& ok) {
  v.assign(static_cast<std::size_t>(rows) * n, 0.f);
  ok.assign(v.size(), 0);
  for (int r = 0; r < rows; ++r)
    for (int k = 0; k < n; ++k) {
      const std::size_t src = static_cast<std::size_t>(r) * cols + (c0 + k) % cols;
      v[static_cast<std::size_t>(r) * n + k] = values[src];
      ok[static_cast<std::size_t>(r) * n + k] = mask[src] > 0;
    }
}

}  // namespace

int main(int argc, char** argv) {
  cxxopts::Options options("bench_scan_picture", "measured scan above its simulation from the same ideal geometry");
  options.add_options()("data", "SemanticKITTI folder", cxxopts::value<std::string>()->default_value(
                                                            "/work/shared/data/semantickitti-seq00-sample"))(
      "scan", "index of the scan in the folder", cxxopts::value<int>()->default_value("0"))(
      "returns", "return model", cxxopts::value<std::string>()->default_value(LIDARSIM_SOURCE_DIR "/data/models/returns_hdl64e.json"))(
      "noise", "range-noise model",
      cxxopts::value<std::string>()->default_value(LIDARSIM_SOURCE_DIR "/data/models/range_noise_hdl64e.json"))(
      "unet", "intensity UNet", cxxopts::value<std::string>()->default_value(LIDARSIM_SOURCE_DIR "/data/models/intensity_unet.h5"))(
      "seed", "seed of the return and noise draws", cxxopts::value<std::uint64_t>()->default_value("1"))(
      "columns", "window width in columns (0 = all)", cxxopts::value<int>()->default_value("256"))(
      "centre-deg", "azimuth of the window centre, deg (0 = straight ahead)", cxxopts::value<double>()->default_value("0"))(
      "scale", "pixels per cell", cxxopts::value<int>()->default_value("2"))(
      "note", "what is held out, under the picture ('|' starts a new line)", cxxopts::value<std::string>()->default_value(""))(
      "out", "PNG", cxxopts::value<std::string>()->default_value("measured_vs_simulated.png"))("h,help", "help");
  try {
    const auto a = options.parse(argc, argv);
    if (a.count("help")) {
      std::printf("%s\n", options.help().c_str());
      return 0;
    }
    for (const char* key : {"returns", "noise", "unet"}) require_file(a[key].as<std::string>(), std::string("--") + key);
    const auto scans = data::list_semantickitti(a["data"].as<std::string>());
    const int index = a["scan"].as<int>();
    if (index < 0 || index >= static_cast<int>(scans.size()))
      throw Error(a["data"].as<std::string>() + ": --scan " + std::to_string(index) + " outside the " +
                  std::to_string(scans.size()) + " scans found");
    const data::ScanFiles& files = scans[static_cast<std::size_t>(index)];
    if (!files.label) throw Error(files.bin.string() + ": no .label file: the UNet and the return target need classes");
    const std::uint64_t seed = a["seed"].as<std::uint64_t>();

    infer::IntensityModel unet = infer::IntensityModel::load(a["unet"].as<std::string>());
    const sensor::ReturnModel returns = sensor::ReturnModel::load(a["returns"].as<std::string>());
    const sensor::RangeNoiseModel noise = sensor::load_range_noise_model(a["noise"].as<std::string>());
    const pgm::BeamLayout& layout = unet.layout();

    // Measured: projected as lidar-infer predict does (plus height for the return target).
    const data::LabelledScan scan = data::read_semantickitti_scan(files);
    pgm::ProjectOptions measured_options;
    measured_options.extra_channels = unet.extra_channels();
    measured_options.extra_channels.push_back("height");
    const std::string id = files.sequence + "_" + files.id;
    const pgm::ProjectionResult measured = pgm::project(scan.points, layout, measured_options, id);
    const pgm::ReturnTarget target = pgm::return_target(measured.pgm);

    // Simulated: the ideal geometry, the return model's draw, range noise, UNet intensity.
    pgm::ProjectOptions ideal_options;
    ideal_options.row_mode = pgm::RowMode::Ring;
    ideal_options.extra_channels = unet.extra_channels();
    pgm::PolarGridMap sim = pgm::project(ideal_points(scan.points, measured, target, layout), layout, ideal_options, id).pgm;
    long geometry = 0;
    for (const float m : std::vector<float>(sim.channel("mask"), sim.channel("mask") + sim.cells())) geometry += m > 0;
    const int dropped = sensor::apply_return_model(returns, sim, seed, 0);
    sensor::apply_range_noise(noise, seed, 0, sim);
    std::vector<float> sim_intensity, measured_intensity;
    unet.predict(sim, sim_intensity);
    // Measured intensity is the recorded one.
    const float* mi = measured.pgm.channel("intensity");
    measured_intensity.assign(mi, mi + measured.pgm.cells());

    long measured_returns = 0;
    for (std::size_t i = 0; i < measured.pgm.cells(); ++i) measured_returns += measured.pgm.channel("mask")[i] > 0;
    std::printf("%s: measured %ld returns; ideal geometry %ld cells (%lld drops filled); simulated %ld returns (%d dropped by the model)\n",
                id.c_str(), measured_returns, geometry, target.drops, geometry - dropped, dropped);

    const int rows = layout.rows(), cols = measured.pgm.cols();
    int n = a["columns"].as<int>();
    if (n <= 0 || n > cols) n = cols;
    // Column of the window centre: the layout's own bin of that direction.
    const double c = a["centre-deg"].as<double>() * M_PI / 180;
    const int centre = layout.column_of(std::cos(c), std::sin(c));
    const int c0 = ((centre - n / 2) % cols + cols) % cols;
    const int scale = std::max(1, a["scale"].as<int>());
    const float range_hi = 50.f;

    TextStyle caption_style, header_style = kHeaderStyle, note_style = caption_style;
    caption_style.scale = header_style.scale = note_style.scale = 1;  // the window is narrow
    auto panel = [&](const float* values, const float* mask, float hi, const std::string& caption, const std::string& hi_label) {
      std::vector<float> v;
      std::vector<std::uint8_t> ok;
      window(values, mask, rows, cols, c0, n, v, ok);
      Image img = field_to_image(v.data(), ok.data(), n, rows, 0.f, hi);
      img = scale_rows(img, scale);
      // Widen by the same factor (scale_rows only repeats rows).
      Image wide(img.width * scale, img.height);
      for (int y = 0; y < img.height; ++y)
        for (int x = 0; x < wide.width; ++x) wide.at(x, y) = img.at(x / scale, y);
      return add_caption_band(wide, caption, ColourKey{"0", hi_label}, caption_style);
    };
    const Image stacked = stack_vertically(
        {panel(measured.pgm.channel("range"), measured.pgm.channel("mask"), range_hi, "measured range", "50 m"),
         panel(sim.channel("range"), sim.channel("mask"), range_hi, "simulated range", "50 m"),
         panel(measured_intensity.data(), measured.pgm.channel("mask"), 1.f, "measured intensity", "1"),
         panel(sim_intensity.data(), sim.channel("mask"), 1.f, "simulated intensity", "1")},
        4);
    char header[256];
    std::snprintf(header, sizeof header, "scan %s, %d columns around %.0f deg, seed %llu (black: no return)", id.c_str(), n,
                  a["centre-deg"].as<double>(), static_cast<unsigned long long>(seed));
    Image picture = add_caption_band(stacked, header, header_style);
    // The note goes below, one band per '|'-separated line (the header band does not wrap).
    std::vector<Image> parts{picture};
    std::string note = a["note"].as<std::string>();
    for (std::size_t start = 0; start < note.size();) {
      const std::size_t end = std::min(note.find('|', start), note.size());
      Image band(picture.width, 1, {255, 255, 255});
      parts.push_back(add_caption_band(band, note.substr(start, end - start), note_style));
      start = end + 1;
    }
    picture = stack_vertically(parts, 0);
    write_png(a["out"].as<std::string>(), picture);  // write_png is atomic (common/atomic_file.h)
    std::printf("wrote %s (%dx%d)\n", a["out"].as<std::string>().c_str(), picture.width, picture.height);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_scan_picture: %s\n", e.what());
    return 1;
  }
}
