// The occlusion raster (per column/row) against the per-cell reference raster
// (tests/sensor/occlusion_reference.h), timed in the same run on the same frames: the object-level
// bench's crowd (bench/synthetic_scenario.h) in the sensor frame after the field of view, on the
// pipeline's grid (one cell per azimuth bin). Process CPU time per frame for each, their ratio,
// and the largest difference in visible fraction.
#include <time.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cxxopts.hpp>
#include <filesystem>
#include <numbers>
#include <vector>

#include "bench/synthetic_scenario.h"
#include "sensor/fov.h"
#include "sensor/frames.h"
#include "sensor/occlusion.h"
#include "tests/sensor/occlusion_reference.h"

using namespace lidarsim;
namespace fs = std::filesystem;

namespace {
double cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}
}  // namespace

int main(int argc, char** argv) {
  const fs::path src = LIDARSIM_SOURCE_DIR;
  cxxopts::Options opts("bench_occlusion", "occlusion raster: per column/row against the per-cell reference");
  opts.add_options()("objects", "objects", cxxopts::value<int>()->default_value("100"))(
      "frames", "frames", cxxopts::value<int>()->default_value("500"))(
      "scenario", "scenario whose sensor is used",
      cxxopts::value<std::string>()->default_value((src / "data/scenarios/demo_urban.json").string()))("h,help", "help");
  try {
    const auto args = opts.parse(argc, argv);
    if (args.count("help")) {
      std::puts(opts.help().c_str());
      return 0;
    }
    const int n = args["objects"].as<int>(), frames = args["frames"].as<int>();
    const sensor::Scenario base = sensor::read_scenario(args["scenario"].as<std::string>());
    const sensor::Scenario sc = bench::synthetic_scenario(n, frames / 10.0 + 1, base);
    const auto cfg = sensor::OcclusionConfig::for_fov(sc.sensor.fov, 2 * std::numbers::pi / sc.sensor.beams.columns);
    // The frames first, so only the rasters are timed.
    std::vector<std::vector<sensor::Object>> scenes;
    sensor::Frame map, ego, sensor_frame;
    for (int k = 0; k < frames; ++k) {
      sensor::sample_frame(sc, sc.frame_time(k), map);
      sensor::map_to_ego(map, ego);
      sensor::ego_to_sensor(ego, sc.sensor.mount, sensor_frame);
      sensor::apply_fov(sensor_frame.objects, sc.sensor.fov);
      scenes.push_back(sensor_frame.objects);
    }
    sensor::Occlusion now(cfg);
    sensor::reference::ReferenceOcclusion before(cfg);
    std::vector<sensor::LanePolyline> lanes;
    double t_now = 0, t_before = 0, worst = 0;
    long cells = 0;
    for (auto& scene : scenes) {
      std::vector<sensor::Object> a = scene, b = scene;
      double c0 = cpu_seconds();
      now.apply(a, lanes);
      double c1 = cpu_seconds();
      before.apply(b);
      double c2 = cpu_seconds();
      t_now += c1 - c0;
      t_before += c2 - c1;
      for (std::size_t i = 0; i < a.size(); ++i) {
        worst = std::max(worst, std::abs(a[i].visible_fraction - b[i].visible_fraction));
        cells += now.footprint_cells()[i];
      }
    }
    double load[3] = {0, 0, 0};
    if (getloadavg(load, 3) < 0) load[0] = -1;
    std::printf("occlusion, %d objects, %d frames, grid %d x %d, %.0f footprint cells per frame\n", n, frames,
                static_cast<int>(std::ceil((cfg.elevation_max - cfg.elevation_min) / cfg.elevation_resolution)),
                sc.sensor.beams.columns, double(cells) / frames);
    std::printf("  now (per column and row): %.1f us/frame CPU\n", 1e6 * t_now / frames);
    std::printf("  before (per cell, tests/sensor/occlusion_reference.h): %.1f us/frame CPU\n",
                1e6 * t_before / frames);
    std::printf("  before / now: %.1f x; largest difference in visible fraction %.4f; load average %.2f\n",
                t_before / t_now, worst, load[0]);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
