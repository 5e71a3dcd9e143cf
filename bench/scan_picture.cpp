// A measured scan above its simulation from the same ideal geometry:
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

// A measured scan and its simulation from the same ideal geometry.
struct ScanPair {
  std::string id;
  pgm::ProjectionResult measured;
  pgm::PolarGridMap sim;
  std::vector<float> measured_intensity, sim_intensity;
};

// Measured: projected as lidar-infer predict does (plus height for the return target).
// Simulated: the ideal geometry, the return model's draw, range noise, UNet intensity.
ScanPair simulate_pair(const data::ScanFiles& files, infer::IntensityModel& unet, const sensor::ReturnModel& returns,
                       const sensor::RangeNoiseModel& noise, std::uint64_t seed) {
  ScanPair p;
  const pgm::BeamLayout& layout = unet.layout();
  const data::LabelledScan scan = data::read_semantickitti_scan(files);
  pgm::ProjectOptions measured_options;
  measured_options.extra_channels = unet.extra_channels();
  measured_options.extra_channels.push_back("height");
  p.id = files.sequence + "_" + files.id;
  p.measured = pgm::project(scan.points, layout, measured_options, p.id);
  const pgm::ReturnTarget target = pgm::return_target(p.measured.pgm);

  pgm::ProjectOptions ideal_options;
  ideal_options.row_mode = pgm::RowMode::Ring;
  ideal_options.extra_channels = unet.extra_channels();
  p.sim = pgm::project(ideal_points(scan.points, p.measured, target, layout), layout, ideal_options, p.id).pgm;
  long geometry = 0;
  for (const float m : std::vector<float>(p.sim.channel("mask"), p.sim.channel("mask") + p.sim.cells())) geometry += m > 0;
  const int dropped = sensor::apply_return_model(returns, p.sim, seed, 0);
  sensor::apply_range_noise(noise, seed, 0, p.sim);
  unet.predict(p.sim, p.sim_intensity);
  const float* mi = p.measured.pgm.channel("intensity");  // measured intensity is the recorded one
  p.measured_intensity.assign(mi, mi + p.measured.pgm.cells());

  long measured_returns = 0;
  for (std::size_t i = 0; i < p.measured.pgm.cells(); ++i) measured_returns += p.measured.pgm.channel("mask")[i] > 0;
  std::printf("%s: measured %ld returns; ideal geometry %ld cells (%lld drops filled); simulated %ld returns (%d dropped by the model)\n",
              p.id.c_str(), measured_returns, geometry, target.drops, geometry - dropped, dropped);
  return p;
}

struct PictureWindow {
  int c0 = 0, n = 0, scale = 1;
  double centre_deg = 0;
};

// Four panels of the window (measured and simulated range, then intensity), a header, and the
// note below, one band per '|'-separated line (the header band does not wrap).
Image render_picture(const ScanPair& p, int rows, const PictureWindow& w, std::uint64_t seed, const std::string& note) {
  const int cols = p.measured.pgm.cols();
  const float range_hi = 50.f;
  TextStyle caption_style, header_style = kHeaderStyle, note_style = caption_style;
  caption_style.scale = header_style.scale = note_style.scale = 1;  // the window is narrow
  auto panel = [&](const float* values, const float* mask, float hi, const std::string& caption, const std::string& hi_label) {
    std::vector<float> v;
    std::vector<std::uint8_t> ok;
    window(values, mask, rows, cols, w.c0, w.n, v, ok);
    Image img = field_to_image(v.data(), ok.data(), w.n, rows, 0.f, hi);
    img = scale_rows(img, w.scale);
    // Widen by the same factor (scale_rows only repeats rows).
    Image wide(img.width * w.scale, img.height);
    for (int y = 0; y < img.height; ++y)
      for (int x = 0; x < wide.width; ++x) wide.at(x, y) = img.at(x / w.scale, y);
    return add_caption_band(wide, caption, ColourKey{"0", hi_label}, caption_style);
  };
  const float* measured_mask = p.measured.pgm.channel("mask");
  const float* sim_mask = p.sim.channel("mask");
  const Image stacked = stack_vertically(
      {panel(p.measured.pgm.channel("range"), measured_mask, range_hi, "measured range", "50 m"),
       panel(p.sim.channel("range"), sim_mask, range_hi, "simulated range", "50 m"),
       panel(p.measured_intensity.data(), measured_mask, 1.f, "measured intensity", "1"),
       panel(p.sim_intensity.data(), sim_mask, 1.f, "simulated intensity", "1")},
      4);
  char header[256];
  std::snprintf(header, sizeof header, "scan %s, %d columns around %.0f deg, seed %llu (black: no return)", p.id.c_str(),
                w.n, w.centre_deg, static_cast<unsigned long long>(seed));
  Image picture = add_caption_band(stacked, header, header_style);
  std::vector<Image> parts{picture};
  for (std::size_t start = 0; start < note.size();) {
    const std::size_t end = std::min(note.find('|', start), note.size());
    Image band(picture.width, 1, {255, 255, 255});
    parts.push_back(add_caption_band(band, note.substr(start, end - start), note_style));
    start = end + 1;
  }
  return stack_vertically(parts, 0);
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
    const ScanPair pair = simulate_pair(files, unet, returns, noise, seed);

    const pgm::BeamLayout& layout = unet.layout();
    const int cols = pair.measured.pgm.cols();
    PictureWindow w;
    w.n = a["columns"].as<int>();
    if (w.n <= 0 || w.n > cols) w.n = cols;
    // Column of the window centre: the layout's own bin of that direction.
    w.centre_deg = a["centre-deg"].as<double>();
    const double c = w.centre_deg * M_PI / 180;
    const int centre = layout.column_of(std::cos(c), std::sin(c));
    w.c0 = ((centre - w.n / 2) % cols + cols) % cols;
    w.scale = std::max(1, a["scale"].as<int>());
    const Image picture = render_picture(pair, layout.rows(), w, seed, a["note"].as<std::string>());
    write_png(a["out"].as<std::string>(), picture);  // write_png is atomic (common/atomic_file.h)
    std::printf("wrote %s (%dx%d)\n", a["out"].as<std::string>().c_str(), picture.width, picture.height);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_scan_picture: %s\n", e.what());
    return 1;
  }
}
