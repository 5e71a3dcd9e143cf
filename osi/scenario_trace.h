#pragma once
// Our scenario JSON -> osi3.SensorView, one per frame: an OSI trace to try `lidar-infer osi`
// and the FMU without a simulator, and the input of the OSI tests and the latency bench.
//
// The host is a moving object with id kHostId (a 4.5 x 1.8 x 1.5 m car whose rear axle is
// 1.4 m behind its box centre and 0.3 m above the road), placed so that its rear axle sits
// above the scenario's ego point; the mounting position is the scenario's mount expressed in
// the OSI vehicle frame (rear-axle centre). Objects keep their scenario ids; lanes become lane
// boundaries with ids kLaneIdBase + their id. Velocities and accelerations are over ground.
// Scenery becomes stationary objects with ids kSceneryIdBase + their index: one per box, a tree as
// one TYPE_TREE box (scenario_trace.cpp says which classes OSI has no type for).
#include <cstdint>

#include "osi/osi3_subset.pb.h"
#include "sensor/scenario.h"

namespace lidarsim::osi {

inline constexpr std::uint64_t kHostId = 1000000;
inline constexpr std::uint64_t kLaneIdBase = 2000000;
inline constexpr std::uint64_t kSceneryIdBase = 3000000;
inline constexpr std::uint64_t kSensorId = 1;
// The host's box and rear axle as the converter writes them.
inline constexpr double kHostLength = 4.5, kHostWidth = 1.8, kHostHeight = 1.5;
inline constexpr double kRearAxleBehindCentre = 1.4, kRearAxleHeight = 0.3;

// The SensorView of `scenario` at time t (out is cleared first).
void sensor_view_from_scenario(const sensor::Scenario& scenario, double t, osi3::SensorView& out);

}  // namespace lidarsim::osi
