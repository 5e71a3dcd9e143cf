// Object-level sensor model throughput: tracking (Kalman + Hungarian) and the KPI manager
// (calibrated default model) for N objects per frame. The requirement is >= 1000
// frames/s for 100 objects; this prints frames/s and the ratio to that requirement.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cxxopts.hpp>
#include <filesystem>
#include <random>

#include "sensor/kpi_manager.h"
#include "sensor/kpi_model.h"
#include "sensor/tracking.h"

using namespace lidarsim::sensor;

// The shipped calibrated model, found from this source file's place in the repository.
static std::string default_model() {
  return (std::filesystem::path(__FILE__).parent_path().parent_path() / "data/models/kpi_pointrcnn.json").string();
}

int main(int argc, char** argv) {
  cxxopts::Options opts("bench_object_model", "tracking + KPI manager frames per second");
  opts.add_options()("objects", "objects per frame", cxxopts::value<int>()->default_value("100"))(
      "frames", "frames", cxxopts::value<int>()->default_value("20000"))(
      "model", "KPI model", cxxopts::value<std::string>()->default_value(default_model()))(
      "h,help", "help");
  const auto args = opts.parse(argc, argv);
  if (args.count("help")) {
    std::puts(opts.help().c_str());
    return 0;
  }
  try {
    const int n = args["objects"].as<int>(), frames = args["frames"].as<int>();
    const KpiModel model = load_kpi_model(args["model"].as<std::string>());
    std::mt19937 rng(1);
    std::uniform_real_distribution<double> u(0, 1);
    // Objects on a 10 x 10 grid of lanes ahead, moving along x; classes mixed.
    std::vector<Object> objects(n);
    for (int i = 0; i < n; ++i) {
      Object& o = objects[i];
      o.id = i + 1;
      o.cls = i % 5 == 3 ? ObjectClass::Pedestrian : i % 5 == 4 ? ObjectClass::Cyclist : ObjectClass::Car;
      o.position = {5 + 7.0 * (i / 10), -20 + 4.0 * (i % 10), -0.9};
      o.velocity = {o.cls == ObjectClass::Pedestrian ? 1.2 : 8.0 * (u(rng) - 0.5), 0, 0};
      o.size = o.cls == ObjectClass::Car ? Eigen::Vector3d(4.2, 1.8, 1.5) : Eigen::Vector3d(0.8, 0.6, 1.7);
    }
    Tracker tracker;
    KpiManager kpi(model, 1);
    std::vector<Object> visible, tracked, reported;
    visible.reserve(n);
    std::vector<int> hidden(n, 0);
    double t_track = 0, t_kpi = 0;
    long reported_total = 0;
    using clock = std::chrono::steady_clock;
    const double dt = 0.1;
    for (int f = 0; f < frames; ++f) {
      visible.clear();
      for (int i = 0; i < n; ++i) {
        Object& o = objects[i];
        o.position += o.velocity * dt;
        if (o.position.x() > 75) o.position.x() = 5;  // wrap around: a new appearance
        if (o.position.x() < 5) o.position.x() = 75;
        if (hidden[i] > 0) --hidden[i];
        else if (u(rng) < 0.01) hidden[i] = 5;  // short occlusions
        if (hidden[i] == 0) visible.push_back(o);
      }
      const auto a = clock::now();
      tracker.update(visible, f * dt);
      tracker.reported(tracked);
      const auto b = clock::now();
      kpi.apply(tracked, reported);
      const auto c = clock::now();
      t_track += std::chrono::duration<double>(b - a).count();
      t_kpi += std::chrono::duration<double>(c - b).count();
      reported_total += reported.size();
    }
    const double total = t_track + t_kpi;
    std::printf("objects %d, frames %d: tracking %.1f us/frame, KPI manager %.1f us/frame, total %.1f us/frame\n", n,
                frames, 1e6 * t_track / frames, 1e6 * t_kpi / frames, 1e6 * total / frames);
    std::printf("object-level model: %.0f frames/s (%.1f x the 1000 frames/s requirement); %.1f objects reported/frame\n",
                frames / total, frames / total / 1000, double(reported_total) / frames);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
