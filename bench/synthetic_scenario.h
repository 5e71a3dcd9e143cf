#pragma once
// The object-level benchmarks' scene (bench_pipeline, bench_growth), built in memory.
#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>
#include <string>

#include "sensor/scenario.h"

namespace lidarsim::bench {

// n objects around an ego driving at 10 m/s: each object circles the ego at its own radius
// (6 to 60 m, uniform density over that ring) and angular speed while travelling with it, so all stay in view for any duration,
// overtake each other and hide each other. Keyframes every second carry the exact position,
// velocity and acceleration of that motion (the reader's quintic Hermite follows it closely).
inline sensor::Scenario synthetic_scenario(int n, double duration, const sensor::Scenario& base) {
  sensor::Scenario s;
  s.name = "synthetic_" + std::to_string(n);
  s.source = "bench/synthetic_scenario.h (in memory)";
  s.duration = duration;
  s.rate_hz = 10;
  s.sensor = base.sensor;
  s.sensor.fov.range_max = 120;
  const double v_ego = 10;
  auto state = [](double t, Eigen::Vector3d p, Eigen::Vector3d v, Eigen::Vector3d a) {
    sensor::KinematicState k;
    k.t = t;
    k.position = p;
    k.velocity = v;
    k.acceleration = a;
    k.heading = std::atan2(v.y(), v.x());
    return k;
  };
  s.ego = {state(0, {0, 0, 0}, {v_ego, 0, 0}, {0, 0, 0}),
           state(duration, {v_ego * duration, 0, 0}, {v_ego, 0, 0}, {0, 0, 0})};
  std::mt19937 rng(42);
  std::uniform_real_distribution<double> u(0, 1);
  const int keyframes = static_cast<int>(std::ceil(duration)) + 1;
  for (int i = 0; i < n; ++i) {
    sensor::ScenarioObject o;
    o.id = i + 1;
    const int kind = i % 10;
    o.cls = kind < 6 ? sensor::ObjectClass::Car
            : kind == 6 ? sensor::ObjectClass::Truck
            : kind < 9 ? sensor::ObjectClass::Pedestrian
                       : sensor::ObjectClass::Cyclist;
    o.size = o.cls == sensor::ObjectClass::Car     ? Eigen::Vector3d(4.5, 1.8, 1.5)
             : o.cls == sensor::ObjectClass::Truck ? Eigen::Vector3d(10, 2.5, 3.5)
             : o.cls == sensor::ObjectClass::Pedestrian ? Eigen::Vector3d(0.6, 0.6, 1.8)
                                                         : Eigen::Vector3d(1.8, 0.6, 1.7);
    o.material = sensor::default_material(o.cls);
    // Uniform density over the ring 6..60 m (a crowd, not a cluster at the sensor).
    const double r = std::sqrt(36 + (3600 - 36) * u(rng)), phase = 2 * std::numbers::pi * u(rng);
    const double w = (u(rng) < 0.5 ? -1 : 1) * (0.02 + 0.1 * u(rng));  // rad/s
    const double z = o.size.z() / 2;
    for (int k = 0; k < keyframes; ++k) {
      const double t = std::min<double>(k, duration), a = phase + w * t;
      const Eigen::Vector3d p(v_ego * t + r * std::cos(a), r * std::sin(a), z);
      const Eigen::Vector3d v(v_ego - r * w * std::sin(a), r * w * std::cos(a), 0);
      const Eigen::Vector3d acc(-r * w * w * std::cos(a), -r * w * w * std::sin(a), 0);
      o.states.push_back(state(t, p, v, acc));
      if (t >= duration) break;
    }
    s.objects.push_back(o);
  }
  return s;
}

}  // namespace lidarsim::bench
