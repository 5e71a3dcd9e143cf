// Soak run of the OSMP FMU: --minutes of simulated time at --rate Hz through
// lidarsim_osi.fmu as an importer drives it (unzip, dlopen, fmi2Instantiate, set the SensorView
// pointer integers, fmi2DoStep, read the SensorData pointer), in this process. The scene never
// ends: the host drives at 10 m/s along x, --objects cars and crossing pedestrians stay in a window
// around it (wrapping round when they leave it, so tracks end and start all the time), and two lane
// boundaries follow it. For each simulated minute it prints the step time (set + DoStep + get;
// building and serializing the SensorView is the importer's and not counted) median and p99 and the
// process's resident memory at the end of the minute; the summary compares the first and the last
// minute. Memory or time that grows with the run shows there.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cxxopts.hpp>
#include <filesystem>
#include <fstream>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <string_view>
#include <vector>

#include "bench/osi_bench_scene.h"
#include "bench/osi_fmu_host.h"
#include "osi/osi3_subset.pb.h"
#include "osi/sensor_view.h"

namespace fs = std::filesystem;

namespace {

[[noreturn]] void die(const std::string& what) {
  std::fprintf(stderr, "bench_osi_soak: %s\n", what.c_str());
  std::exit(1);
}

long rss_kib() {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("VmRSS:", 0) == 0) return std::stol(line.substr(6));
  return -1;
}

struct Window {
  double median = 0, p99 = 0;
};
Window window(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return {v[v.size() / 2], v[std::min(v.size() - 1, v.size() * 99 / 100)]};
}

struct Mover {
  double x0, y0, vx, vy;
  bool ped;
};

// Wraps v into [lo, lo + span).
double wrap(double v, double lo, double span) { return lo + std::fmod(std::fmod(v - lo, span) + span, span); }

void make_view(const std::vector<Mover>& movers, double t, osi3::SensorView& v) {
  v.Clear();
  lidarsim::osi::set_timestamp(t, *v.mutable_timestamp());
  v.mutable_sensor_id()->set_value(1);
  v.mutable_host_vehicle_id()->set_value(1000);
  v.mutable_mounting_position()->mutable_position()->set_x(1.4);
  v.mutable_mounting_position()->mutable_position()->set_z(1.43);
  auto& gt = *v.mutable_global_ground_truth();
  auto add = [&](std::uint64_t id, bool ped, double x, double y, double vx, double vy) {
    return lidarsim::bench::add_bench_object(gt, id, ped, x, y, vx, vy);
  };
  const double host_x = 10 * t;
  auto* host = add(1000, false, host_x + 1.4, 0, 10, 0);
  host->mutable_vehicle_attributes()->mutable_bbcenter_to_rear()->set_x(-1.4);
  host->mutable_vehicle_attributes()->mutable_bbcenter_to_rear()->set_z(-0.45);
  for (std::size_t i = 0; i < movers.size(); ++i) {
    const Mover& m = movers[i];
    double rx = wrap(m.x0 + (m.vx - 10) * t, -30, 90);
    const double y = m.ped ? wrap(m.y0 + m.vy * t, -20, 40) : m.y0;
    if (std::abs(y) < 3 && std::abs(rx) < 8) rx += 16;  // never on top of the host
    add(i + 1, m.ped, host_x + rx, y, m.vx, m.vy);
  }
  const double x_start = 10 * std::floor((host_x - 50) / 10);
  for (int side : {-1, 1}) {
    auto* l = gt.add_lane_boundary();
    l->mutable_id()->set_value(side < 0 ? 2001 : 2002);
    l->mutable_classification()->set_type(osi3::LaneBoundary::Classification::TYPE_SOLID_LINE);
    for (double x = x_start; x <= x_start + 250; x += 10) {
      auto* p = l->add_boundary_line()->mutable_position();
      p->set_x(x);
      p->set_y(side * 1.75);
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  cxxopts::Options opts("bench_osi_soak", "a long run of the OSMP FMU: step time and memory per simulated minute");
  opts.add_options()
    ("fmu", "the FMU", cxxopts::value<std::string>()->default_value("build/lidarsim_osi.fmu"))
    ("minutes", "simulated minutes", cxxopts::value<double>()->default_value("30"))
    ("rate", "frames per simulated second (the FMU's step is 1/rate)", cxxopts::value<double>()->default_value("10"))
    ("objects", "moving objects besides the host", cxxopts::value<int>()->default_value("20"))
    ("h,help", "this text");
  const auto args = opts.parse(argc, argv);
  if (args.count("help")) {
    std::printf("%s\n", opts.help().c_str());
    return 0;
  }
  const double minutes = args["minutes"].as<double>(), rate = args["rate"].as<double>();
  const int objects = args["objects"].as<int>();
  if (!(minutes > 0) || !(rate > 0) || objects < 0) die("--minutes and --rate must be positive, --objects >= 0");
  const fs::path fmu = fs::absolute(args["fmu"].as<std::string>());
  if (!fs::exists(fmu)) die(fmu.string() + ": no such file (build lidarsim_osi_fmu_package)");

  std::unique_ptr<lidarsim::bench::FmuHost> host;
  try {
    host = std::make_unique<lidarsim::bench::FmuHost>(fmu, "soak");
  } catch (const std::exception& e) {
    die(e.what());
  }

  std::mt19937 rng(3);
  std::uniform_real_distribution<double> ux(-30, 60), uy(-20, 20), uv(8, 14);
  std::vector<Mover> movers;
  for (int i = 0; i < objects; ++i) {
    const bool ped = i % 5 == 4;
    const double y = uy(rng);
    movers.push_back({ux(rng), y, ped ? 10.0 : uv(rng), ped ? (y > 0 ? -1.4 : 1.4) : 0.0, ped});
  }

  const long frames = std::lround(minutes * 60 * rate);
  const long per_minute = std::max(1L, std::lround(60 * rate));
  osi3::SensorView view;
  std::string bytes;
  std::vector<double> ms;
  Window first{}, last{};
  long rss_first = 0, rss_last = 0, detections = 0;
  std::printf("| simulated minute | frames | step median (ms) | step p99 (ms) | RSS (MiB) |\n|---:|---:|---:|---:|---:|\n");
  for (long k = 0; k < frames; ++k) {
    const double t = static_cast<double>(k) / rate;
    make_view(movers, t, view);
    view.SerializeToString(&bytes);
    const auto start = std::chrono::steady_clock::now();
    std::string_view out;
    try {
      out = host->step(bytes, t, 1 / rate);
    } catch (const std::exception& e) {
      die(std::string(e.what()) + " (frame " + std::to_string(k) + ")");
    }
    ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
    if (k == frames - 1) {  // the last output, decoded once to show it is whole
      osi3::SensorData data;
      if (!data.ParseFromArray(out.data(), static_cast<int>(out.size()))) die("the last SensorData does not parse");
      if (data.feature_data().lidar_sensor_size() > 0) detections = data.feature_data().lidar_sensor(0).detection_size();
    }
    if (static_cast<long>(ms.size()) == per_minute || k == frames - 1) {
      const Window w = window(ms);
      const long rss = rss_kib();
      std::printf("| %ld | %zu | %.1f | %.1f | %.1f |\n", (k + 1 + per_minute - 1) / per_minute, ms.size(), w.median,
                  w.p99, rss / 1024.0);
      std::fflush(stdout);
      if (k < per_minute) {
        first = w;
        rss_first = rss;
      }
      last = w;
      rss_last = rss;
      ms.clear();
    }
  }
  std::printf("\n%ld frames (%.1f simulated minutes at %.0f Hz, %d objects, %ld lidar detections in the last frame)\n",
              frames, minutes, rate, objects, detections);
  std::printf("first minute: median %.1f ms, p99 %.1f ms, RSS %.1f MiB; last minute: median %.1f ms, p99 %.1f ms, RSS %.1f MiB\n",
              first.median, first.p99, rss_first / 1024.0, last.median, last.p99, rss_last / 1024.0);
  return 0;
}
