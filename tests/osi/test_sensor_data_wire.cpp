// osi::encode_sensor_data (the hand-written wire encoder) against libprotobuf: for many random
// frames, the bytes equal SerializeToString of the message build_sensor_data fills from the same
// frame. Any field dropped, misnumbered, of the wrong wire type or out of field order changes the
// bytes; the frames reach every branch (false positives, unknown truth ids, coasting tracks, every
// class, lanes without an OSI id, empty and several detectors, ids of every varint length,
// negative seconds, echoed messages with fields we do not know).
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "common/error.h"
#include "infer/osi_runner.h"
#include "osi/osi3_subset.pb.h"
#include "osi/sensor_data.h"
#include "osi/sensor_view.h"
#include "osi/sensor_view_decoder.h"
#include "osi/trace.h"
#include "sensor/frames.h"

namespace {

using lidarsim::osi::CloudRef;
using lidarsim::osi::ReportedDetection;
using lidarsim::osi::SceneFrame;

// A random frame: the scene, what the model reported, and the point clouds it refers to.
struct RandomFrame {
  SceneFrame scene;
  std::vector<ReportedDetection> objects;
  std::vector<lidarsim::sensor::LanePolynomial> lanes;
  std::vector<lidarsim::pgm::BeamLayout> layouts;
  std::vector<std::vector<float>> range, intensity, object_id;
  std::vector<std::vector<int>> cell;
  std::vector<CloudRef> clouds;
  lidarsim::osi::IdMap ids;
};

class Draw {
 public:
  explicit Draw(unsigned seed) : rng_(seed) {}
  double real(double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng_); }
  int integer(int lo, int hi) { return std::uniform_int_distribution<int>(lo, hi)(rng_); }
  bool coin(double p = 0.5) { return std::bernoulli_distribution(p)(rng_); }
  // Ids of every varint length, 1 to 10 bytes.
  std::uint64_t id() { return std::uniform_int_distribution<std::uint64_t>()(rng_) >> integer(0, 63); }
  Eigen::Vector3d vec(double s) { return {real(-s, s), real(-s, s), real(-s, s)}; }

 private:
  std::mt19937_64 rng_;
};

// A message built with libprotobuf as the scene carries it (decoded from its bytes).
template <class M, class P>
M decoded(const P& message) {
  M m;
  lidarsim::osi::decode_message(message.SerializeAsString(), m);
  return m;
}

// Some fields set, some not (proto2 presence), sometimes a field our subset does not know
// (MountingPosition 99, as a newer OSI could add): libprotobuf echoes it, so must we.
lidarsim::osi::msg::MountingPosition random_mount(Draw& d) {
  osi3::MountingPosition m;
  if (d.coin(0.8)) {
    m.mutable_position()->set_x(d.real(-3, 3));
    if (d.coin()) m.mutable_position()->set_z(d.real(0, 2));
  }
  if (d.coin()) m.mutable_orientation()->set_yaw(d.real(-3, 3));
  if (d.coin(0.2)) m.mutable_unknown_fields()->AddVarint(99, d.id());
  return decoded<lidarsim::osi::msg::MountingPosition>(m);
}

lidarsim::sensor::Pose random_pose(Draw& d) {
  const double yaw = d.real(-3.2, 3.2);
  lidarsim::sensor::Pose p;
  p.rotation << std::cos(yaw), -std::sin(yaw), 0, std::sin(yaw), std::cos(yaw), 0, 0, 0, 1;
  p.translation = d.vec(50);
  return p;
}

void random_cloud(Draw& d, RandomFrame& f, int model_ids) {
  const int rows = d.integer(1, 64), columns = d.integer(1, 2048);
  f.layouts.push_back(lidarsim::pgm::BeamLayout::uniform(rows, d.real(0, 20), d.real(-30, -1), columns));
  const int n = d.coin(0.2) ? 0 : d.integer(1, 3000);
  auto& r = f.range.emplace_back(), &in = f.intensity.emplace_back(), &id = f.object_id.emplace_back();
  auto& cell = f.cell.emplace_back();
  for (int i = 0; i < n; ++i) {
    r.push_back(static_cast<float>(d.real(0.5, 120)));
    in.push_back(static_cast<float>(d.real(0, 1)));
    // road and paint (< 0), known ids, ids the map never saw, and not quite integers
    id.push_back(d.coin(0.3) ? -1.0f : static_cast<float>(d.integer(0, model_ids + 5)) + (d.coin(0.1) ? 0.3f : 0.0f));
    cell.push_back(d.integer(0, rows * columns - 1));
  }
}

RandomFrame random_frame(unsigned seed) {
  Draw d(seed);
  RandomFrame f;
  const int model_ids = d.integer(0, 40);
  for (int i = 0; i < model_ids; ++i) f.ids.to_model(d.id());
  SceneFrame& s = f.scene;
  osi3::Timestamp timestamp;
  timestamp.set_seconds(d.coin(0.2) ? -d.integer(1, 1 << 30) : d.integer(0, 1 << 30));
  if (d.coin(0.8)) timestamp.set_nanos(static_cast<std::uint32_t>(d.integer(0, 999999999)));
  s.timestamp = decoded<lidarsim::osi::msg::Timestamp>(timestamp);
  osi3::Identifier sensor_id;
  if (d.coin(0.9)) sensor_id.set_value(d.id());  // else present but empty, as an input without it gives
  s.sensor_id = decoded<lidarsim::osi::msg::Identifier>(sensor_id);
  s.mounting_position = random_mount(d);
  s.map.ego_in_map = random_pose(d);
  s.mount = random_pose(d);
  s.host_velocity = d.vec(20);
  s.host_acceleration = d.vec(3);
  const int detectors = d.integer(1, 3);
  for (int k = 0; k < detectors; ++k) {
    lidarsim::osi::Detector det;
    osi3::Identifier id;
    id.set_value(d.id());
    if (d.coin(0.1)) id.mutable_unknown_fields()->AddFixed64(5, d.id());
    det.sensor_id = decoded<lidarsim::osi::msg::Identifier>(id);
    det.mounting_position = random_mount(d);
    s.detectors.push_back(det);
    random_cloud(d, f, model_ids);
  }
  const int objects = d.integer(0, 30);
  for (int i = 0; i < objects; ++i) {
    ReportedDetection r;
    r.object.id = d.coin(0.8) ? d.integer(0, 1 << 20) : -d.integer(1000, 1 << 30);  // tracks, false positives
    r.object.cls = static_cast<lidarsim::sensor::ObjectClass>(d.integer(0, lidarsim::sensor::kNumObjectClasses - 1));
    r.object.position = d.vec(80);
    r.object.velocity = d.vec(20);
    r.object.acceleration = d.vec(3);
    r.object.size = d.vec(5).cwiseAbs();
    r.object.heading = d.real(-10, 10);
    r.object.score = d.real(-0.5, 1.5);
    r.truth_id = d.coin(0.2) ? -1 : d.integer(0, model_ids + 3);
    r.coasting = d.coin(0.3);
    f.objects.push_back(r);
  }
  const int lanes = d.integer(0, 4);
  for (int i = 0; i < lanes; ++i) {
    lidarsim::sensor::LanePolynomial p;
    p.id = d.coin(0.8) ? d.integer(0, model_ids + 2) : -1;
    p.type = static_cast<lidarsim::sensor::LaneType>(d.integer(0, 2));
    p.c0 = d.real(-5, 5), p.c1 = d.real(-0.1, 0.1), p.c2 = d.real(-1e-3, 1e-3), p.c3 = d.real(-1e-5, 1e-5);
    p.x_min = d.real(-10, 20);
    p.x_max = p.x_min + d.real(-1, 60);  // also empty ranges: still two points
    f.lanes.push_back(p);
  }
  for (std::size_t k = 0; k < f.layouts.size(); ++k) {
    CloudRef c;
    c.size = f.range[k].size();
    c.range = f.range[k].data();
    c.intensity = f.intensity[k].data();
    c.object_id = f.object_id[k].data();
    c.cell = f.cell[k].data();
    c.layout = c.size == 0 && k % 2 == 0 ? nullptr : &f.layouts[k];  // as without the point cloud
    f.clouds.push_back(c);
  }
  return f;
}

std::string first_difference(const std::string& a, const std::string& b) {
  std::size_t i = 0;
  while (i < a.size() && i < b.size() && a[i] == b[i]) ++i;
  return "sizes " + std::to_string(a.size()) + " and " + std::to_string(b.size()) + ", first difference at byte " +
         std::to_string(i);
}

}  // namespace

TEST(OsiSensorDataWire, EncoderGivesLibprotobufsBytesForRandomFrames) {
  std::string ours = "left over from a bigger frame, to be overwritten" + std::string(100000, 'x');
  osi3::SensorData message;
  for (unsigned seed = 1; seed <= 200; ++seed) {
    const RandomFrame f = random_frame(seed);
    const std::uint64_t cycle = seed % 3 == 0 ? 0 : std::uint64_t{1} << (seed % 64);
    lidarsim::osi::build_sensor_data(f.scene, f.objects, f.lanes, f.clouds, f.ids, cycle, message);
    const std::string expected = message.SerializeAsString();
    lidarsim::osi::encode_sensor_data(f.scene, f.objects, f.lanes, f.clouds, f.ids, cycle, ours);
    ASSERT_EQ(ours, expected) << "seed " << seed << ": " << first_difference(ours, expected);
    // With room for a trace's length field in front: the same bytes after it.
    lidarsim::osi::encode_sensor_data(f.scene, f.objects, f.lanes, f.clouds, f.ids, cycle, ours,
                                      lidarsim::osi::kLengthBytes);
    ASSERT_EQ(ours.substr(lidarsim::osi::kLengthBytes), expected) << "seed " << seed;
  }
}

TEST(OsiSensorDataWire, EncoderRefusesCloudsThatDoNotMatchTheDetectors) {
  RandomFrame f = random_frame(7);
  f.clouds.pop_back();
  std::string out;
  EXPECT_THROW(lidarsim::osi::encode_sensor_data(f.scene, f.objects, f.lanes, f.clouds, f.ids, 0, out),
               lidarsim::Error);
}

// The runner on the whole model (~56 k detections): its bytes are its message serialized.
TEST(OsiSensorDataWire, RunnerBytesEqualItsMessageSerializedOnTheWholeModel) {
  const std::string src = LIDARSIM_SOURCE_DIR;
  auto runner = lidarsim::infer::OsiRunner::from_files(src + "/data/scenarios/demo_urban.json",
                                                       src + "/data/models/kpi_pointrcnn.json",
                                                       src + "/data/models/intensity_unet.h5");
  std::ifstream in(src + "/tests/osi/data/demo_sv_osi_3.5.0.osi", std::ios::binary);
  lidarsim::osi::TraceReader reader(in, "demo_sv_osi_3.5.0.osi");
  osi3::SensorView view;
  osi3::SensorData message;
  std::string bytes;
  for (int k = 0; k < 2 && reader.next(view); ++k) {
    runner.step(view, k, "trace", bytes);
    runner.last_sensor_data(message);
    ASSERT_GT(runner.reported_points(), 10000u);
    ASSERT_EQ(bytes, message.SerializeAsString()) << "frame " << k;
  }
}
