// Class mix per laser band: simulated demo frames against the measured SemanticKITTI scans.
//   bench_class_mix [--scenario S.json] [--before B.json] [--data DIR] [--frames 0,20,40,60,80]
//                   [--band 8] [--out docs/class_mix.png]
// Per band of --band lasers (row 0 = the top laser), the share of the band's cells that return
// road (road, parking, lane marking), sidewalk (sidewalk, other ground), building (building,
// other structure), vegetation (vegetation, trunk, terrain), car (car, truck, other vehicle),
// other (everything else: persons, two-wheelers, poles, signs, fences, other objects, unlabeled)
// or nothing. Measured: every labelled scan of --data projected onto the HDL-64E grid (firing
// order), shares pooled over the scans. Simulated: the scenario's frames through `lidar-infer
// sim`'s pipeline (no return model: every beam that meets geometry returns), pooled over
// --frames; "before" is --before, or the same scenario with its scenery removed (boxes on a plane).
// Printed: the shares and the total variation 0.5 sum |p_sim - p_measured| per band, before and
// after, and between the first and last measured scan (the same street 0.2 s apart: a floor, not
// a ceiling across places).
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cxxopts.hpp>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "common/error.h"
#include "common/image.h"
#include "common/plot.h"
#include "data/semantickitti.h"
#include "infer/sim_pipeline.h"
#include "pgm/materials.h"
#include "pgm/projection.h"
#include "sensor/kpi_model.h"
#include "sensor/scenario.h"

using namespace lidarsim;
namespace fs = std::filesystem;

namespace {

constexpr int kCategories = 7;
const char* const kNames[kCategories] = {"road", "sidewalk", "building", "vegetation", "car", "other", "no return"};
const Rgb kColours[kCategories] = {{90, 90, 90},   {200, 150, 200}, {230, 140, 40}, {40, 160, 60},
                                   {40, 90, 220}, {220, 60, 60},   {20, 20, 20}};

int category(int cls) {
  namespace c = pgm::cls;
  switch (cls) {
    case c::road: case c::parking: case c::lane_marking: return 0;
    case c::sidewalk: case c::other_ground: return 1;
    case c::building: case c::other_structure: return 2;
    case c::vegetation: case c::trunk: case c::terrain: return 3;
    case c::car: case c::truck: case c::other_vehicle: return 4;
    default: return 5;
  }
}

// Counts [band][category] pooled over the maps added.
struct BandMix {
  int rows_per_band = 8;
  std::vector<std::array<double, kCategories>> counts;
  void add(const pgm::PolarGridMap& m) {
    const int bands = (m.rows() + rows_per_band - 1) / rows_per_band;
    if (counts.empty()) counts.assign(bands, {});
    const float* cls = m.channel("class");
    const float* mask = m.channel("mask");
    for (int r = 0; r < m.rows(); ++r)
      for (int c = 0; c < m.cols(); ++c) {
        const std::size_t i = static_cast<std::size_t>(r) * m.cols() + c;
        counts[r / rows_per_band][mask[i] > 0 ? category(static_cast<int>(cls[i])) : kCategories - 1] += 1;
      }
  }
  std::array<double, kCategories> shares(int band) const {
    std::array<double, kCategories> s{};
    double total = 0;
    for (double v : counts[band]) total += v;
    for (int k = 0; k < kCategories; ++k) s[k] = total > 0 ? counts[band][k] / total : 0;
    return s;
  }
};

double total_variation(const std::array<double, kCategories>& a, const std::array<double, kCategories>& b) {
  double tv = 0;
  for (int k = 0; k < kCategories; ++k) tv += std::abs(a[k] - b[k]);
  return 0.5 * tv;
}

BandMix simulate(sensor::Scenario scenario, const std::vector<int>& frames, int band) {
  infer::SimOptions options;
  options.intensity = false;
  infer::SimPipeline pipeline(std::move(scenario),
                              sensor::load_kpi_model(fs::path(LIDARSIM_SOURCE_DIR) / "data/models/kpi_pointrcnn.json"),
                              nullptr, options);
  BandMix mix;
  mix.rows_per_band = band;
  infer::SimFrame frame;
  int last = 0;
  for (int k : frames) last = std::max(last, k);
  if (last >= pipeline.frame_count())
    throw Error("--frames: frame " + std::to_string(last) + " beyond the scenario's " +
                std::to_string(pipeline.frame_count()));
  for (int k = 0; k <= last; ++k) {  // frames in order: tracking carries state
    pipeline.run_frame(k, frame, false);
    if (std::find(frames.begin(), frames.end(), k) != frames.end()) mix.add(frame.pgm);
  }
  return mix;
}

void print_shares(const char* label, const std::array<double, kCategories>& s) {
  std::printf("  %-9s", label);
  for (double v : s) std::printf(" %9.3f", v);
  std::printf("\n");
}

Image picture(const BandMix& measured, const BandMix& before, const BandMix& after, const std::string& title) {
  const int bands = static_cast<int>(measured.counts.size());
  ChartSpec spec;
  spec.width = 1200;
  spec.height = 600;
  spec.title = title;
  spec.x_label = "laser band (top to bottom); bars: measured | boxes on a plane | street";
  spec.y_label = "share of the band's cells";
  spec.x_lo = 0;
  spec.x_hi = bands;
  spec.y_lo = 0;
  spec.y_hi = 1.6;  // room above the bars for the legend
  for (int b = 0; b < bands; ++b) {
    const int lo = b * measured.rows_per_band, hi = lo + measured.rows_per_band - 1;
    spec.x_ticks.push_back({b + 0.5, std::to_string(lo) + "-" + std::to_string(hi)});
  }
  Chart chart(spec);
  const BandMix* mixes[3] = {&measured, &before, &after};
  for (int b = 0; b < bands; ++b)
    for (int m = 0; m < 3; ++m) {
      const auto s = mixes[m]->shares(b);
      const double x0 = b + 0.08 + 0.29 * m, x1 = x0 + 0.25;
      double y = 0;
      for (int k = 0; k < kCategories; ++k) {
        chart.bar(x0, x1, y, y + s[k], kColours[k]);
        y += s[k];
      }
    }
  chart.hline(1.0, {120, 120, 120});
  std::vector<LegendEntry> legend;
  for (int k = 0; k < kCategories; ++k) legend.push_back({kNames[k], kColours[k]});
  chart.legend(legend);
  return chart.image();
}

std::vector<int> parse_frames(const std::string& list) {
  std::vector<int> out;
  std::stringstream ss(list);
  std::string item;
  while (std::getline(ss, item, ',')) {
    try {
      out.push_back(std::stoi(item));
    } catch (const std::exception&) {
      throw Error("--frames: '" + item + "' is not a frame number");
    }
    if (out.back() < 0) throw Error("--frames: " + item + " is negative");
  }
  if (out.empty()) throw Error("--frames: no frame given");
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  cxxopts::Options options("bench_class_mix", "class mix per laser band: simulated frames vs measured scans");
  const fs::path src = LIDARSIM_SOURCE_DIR;
  options.add_options()("scenario", "scenario (after)",
                        cxxopts::value<std::string>()->default_value((src / "data/scenarios/demo_urban.json").string()))(
      "before", "scenario before (default: --scenario without its scenery)", cxxopts::value<std::string>()->default_value(""))(
      "data", "SemanticKITTI folder with labels",
      cxxopts::value<std::string>()->default_value((src / "../shared/data/semantickitti-seq00-sample").string()))(
      "frames", "simulated frames, comma-separated", cxxopts::value<std::string>()->default_value("0,20,40,60,80"))(
      "band", "lasers per band", cxxopts::value<int>()->default_value("8"))(
      "out", "PNG (empty: none)", cxxopts::value<std::string>()->default_value(""))("h,help", "help");
  try {
    const auto a = options.parse(argc, argv);
    if (a.count("help")) {
      std::printf("%s\n", options.help().c_str());
      return 0;
    }
    const int band = a["band"].as<int>();
    if (band < 1 || band > 64) throw Error("--band: must be 1..64, got " + std::to_string(band));
    const std::vector<int> frames = parse_frames(a["frames"].as<std::string>());
    const sensor::Scenario after_scenario = sensor::read_scenario(a["scenario"].as<std::string>());
    sensor::Scenario before_scenario = after_scenario;
    if (a["before"].as<std::string>().empty()) before_scenario.scenery.clear();
    else before_scenario = sensor::read_scenario(a["before"].as<std::string>());
    const pgm::BeamLayout layout = after_scenario.sensor.beams.layout();

    BandMix measured, first, last;
    measured.rows_per_band = first.rows_per_band = last.rows_per_band = band;
    std::vector<data::ScanFiles> scans;
    for (const auto& f : data::list_semantickitti(a["data"].as<std::string>()))
      if (f.label) scans.push_back(f);
    if (scans.empty()) throw Error(a["data"].as<std::string>() + ": no labelled scans");
    for (std::size_t i = 0; i < scans.size(); ++i) {
      const auto scan = data::read_semantickitti_scan(scans[i]);
      const auto p = pgm::project(scan.points, layout, {}, scans[i].bin.string());
      measured.add(p.pgm);
      if (i == 0) first.add(p.pgm);
      if (i + 1 == scans.size()) last.add(p.pgm);
    }
    const BandMix before = simulate(before_scenario, frames, band);
    const BandMix after = simulate(after_scenario, frames, band);

    std::printf("class mix per band of %d lasers: %zu measured scans (%s) vs frames %s of %s\n", band, scans.size(),
                a["data"].as<std::string>().c_str(), a["frames"].as<std::string>().c_str(),
                a["scenario"].as<std::string>().c_str());
    std::printf("  %-9s", "");
    for (const char* n : kNames) std::printf(" %9s", n);
    std::printf("\n");
    double tv_before = 0, tv_after = 0, tv_floor = 0;
    const int bands = static_cast<int>(measured.counts.size());
    std::vector<double> tvb(bands), tva(bands), tvf(bands);
    for (int b = 0; b < bands; ++b) {
      std::printf("lasers %d-%d\n", b * band, std::min(layout.rows(), (b + 1) * band) - 1);
      print_shares("measured", measured.shares(b));
      print_shares("before", before.shares(b));
      print_shares("after", after.shares(b));
      tvb[b] = total_variation(before.shares(b), measured.shares(b));
      tva[b] = total_variation(after.shares(b), measured.shares(b));
      tvf[b] = total_variation(first.shares(b), last.shares(b));
      tv_before += tvb[b] / bands;
      tv_after += tva[b] / bands;
      tv_floor += tvf[b] / bands;
    }
    std::printf("\ntotal variation from the measured mix per band (0 = the same mix, 1 = disjoint)\n");
    std::printf("  %-12s %8s %8s %14s\n", "band", "before", "after", "scan 0 vs last");
    for (int b = 0; b < bands; ++b)
      std::printf("  lasers %2d-%-3d %8.3f %8.3f %14.3f\n", b * band, std::min(layout.rows(), (b + 1) * band) - 1, tvb[b],
                  tva[b], tvf[b]);
    std::printf("  %-12s %8.3f %8.3f %14.3f\n", "mean", tv_before, tv_after, tv_floor);
    if (!a["out"].as<std::string>().empty()) {
      char title[160];
      std::snprintf(title, sizeof title, "Class mix per laser band: total variation %.2f (boxes on a plane) -> %.2f (street)",
                    tv_before, tv_after);
      write_png(a["out"].as<std::string>(), picture(measured, before, after, title));
      std::printf("wrote %s\n", a["out"].as<std::string>().c_str());
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
  return 0;
}
