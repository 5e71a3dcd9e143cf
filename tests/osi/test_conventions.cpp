// OSI conventions: where the mount may come from and which wins, the ideal
// model's first frame, the version we write, and traces written by an older version.
//
// Scene (as in test_scene.cpp): the host (99) stands at the origin, a van (11) 15 m ahead, a car
// (12) hidden behind it, a pedestrian (13) crossing 10 m ahead at -1.5 m/s, accelerating at
// -0.5 m/s^2 in y.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>

#include "../data/temp_dir.h"
#include "common/error.h"
#include "infer/osi_runner.h"
#include "osi/osi3_subset.pb.h"
#include "osi/sensor_data.h"
#include "osi/trace.h"
#include "tests/support/file_bytes.h"

using lidarsim::testing::read_bytes;

namespace {

namespace fs = std::filesystem;
using lidarsim::infer::OsiRunner;
using lidarsim::infer::SimOptions;

void add_object(osi3::GroundTruth& gt, std::uint64_t id, osi3::MovingObject::Type type, double x, double y, double z,
                double l, double w, double h, double vy = 0, double ay = 0) {
  auto* o = gt.add_moving_object();
  o->mutable_id()->set_value(id);
  o->set_type(type);
  if (type == osi3::MovingObject::TYPE_VEHICLE)
    o->mutable_vehicle_classification()->set_type(osi3::MovingObject::VehicleClassification::TYPE_MEDIUM_CAR);
  auto* b = o->mutable_base();
  b->mutable_position()->set_x(x);
  b->mutable_position()->set_y(y);
  b->mutable_position()->set_z(z);
  b->mutable_dimension()->set_length(l);
  b->mutable_dimension()->set_width(w);
  b->mutable_dimension()->set_height(h);
  b->mutable_velocity()->set_y(vy);
  b->mutable_acceleration()->set_y(ay);
}

void set_mount(osi3::MountingPosition& m, double x, double z, double yaw = 0) {
  m.mutable_position()->set_x(x);
  m.mutable_position()->set_z(z);
  m.mutable_orientation()->set_yaw(yaw);
}

// The scene at time t without any mount.
osi3::SensorView scene_at(double t) {
  osi3::SensorView v;
  lidarsim::osi::set_timestamp(t, *v.mutable_timestamp());
  v.mutable_sensor_id()->set_value(7);
  v.mutable_host_vehicle_id()->set_value(99);
  auto& gt = *v.mutable_global_ground_truth();
  add_object(gt, 99, osi3::MovingObject::TYPE_VEHICLE, 1.4, 0, 0.75, 4.5, 1.8, 1.5);
  auto* r = gt.mutable_moving_object(0)->mutable_vehicle_attributes()->mutable_bbcenter_to_rear();
  r->set_x(-1.4);
  r->set_z(-0.45);
  add_object(gt, 11, osi3::MovingObject::TYPE_VEHICLE, 15, 0, 1.1, 5, 2, 2.2);
  add_object(gt, 12, osi3::MovingObject::TYPE_VEHICLE, 25, 0, 0.75, 4.5, 1.8, 1.5);
  add_object(gt, 13, osi3::MovingObject::TYPE_PEDESTRIAN, 10, 5 - 1.5 * t, 0.9, 0.6, 0.6, 1.8, -1.5, -0.5);
  return v;
}

OsiRunner make_runner(bool point_cloud, bool ideal = true) {
  const std::string src = LIDARSIM_SOURCE_DIR;
  SimOptions options;
  options.point_cloud = options.intensity = point_cloud;
  if (ideal) lidarsim::infer::make_ideal(options);
  return OsiRunner::from_files(src + "/data/scenarios/demo_urban.json", src + "/data/models/kpi_pointrcnn.json",
                               src + "/data/models/intensity_unet.h5", options);
}

// The serialized SensorData of each frame of `views` through a fresh runner.
std::vector<std::string> run_conventions_cli(const std::vector<osi3::SensorView>& views, bool point_cloud) {
  OsiRunner runner = make_runner(point_cloud);
  std::vector<std::string> out;
  osi3::SensorData d;
  for (std::size_t k = 0; k < views.size(); ++k) {
    runner.step(views[k], static_cast<long>(k), "hand", d);
    out.push_back(d.SerializeAsString());
  }
  return out;
}

osi3::SensorData parsed(const std::string& bytes) {
  osi3::SensorData d;
  EXPECT_TRUE(d.ParseFromString(bytes));
  return d;
}

// The SensorData without its feature data (the virtual sensor's part: objects, lanes, headers).
std::string without_features(const std::string& bytes) {
  osi3::SensorData d = parsed(bytes);
  d.clear_feature_data();
  return d.SerializeAsString();
}

std::string error_of(const osi3::SensorView& v) {
  OsiRunner runner = make_runner(false);
  osi3::SensorData d;
  try {
    runner.step(v, 0, "hand", d);
  } catch (const lidarsim::Error& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(OsiConventions, MountOnlyInLidarViewConfigurationGivesTheSameSensorDataAsTheTopLevelMount) {
  std::vector<osi3::SensorView> top, lidar;
  for (int k = 0; k < 2; ++k) {
    top.push_back(scene_at(0.1 * k));
    set_mount(*top.back().mutable_mounting_position(), 1.0, 1.43);
    lidar.push_back(scene_at(0.1 * k));
    auto* c = lidar.back().add_lidar_sensor_view()->mutable_view_configuration();
    c->mutable_sensor_id()->set_value(70);
    set_mount(*c->mutable_mounting_position(), 1.0, 1.43);
  }
  const auto a = run_conventions_cli(top, true), b = run_conventions_cli(lidar, true);
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t k = 0; k < a.size(); ++k) {
    // The same bytes but for the detector's id: the view configuration's (70), else the SensorView's (7).
    osi3::SensorData da = parsed(a[k]), db = parsed(b[k]);
    ASSERT_EQ(db.feature_data().lidar_sensor_size(), 1);
    EXPECT_EQ(da.feature_data().lidar_sensor(0).header().sensor_id().value(), 7u);
    EXPECT_EQ(db.feature_data().lidar_sensor(0).header().sensor_id().value(), 70u);
    db.mutable_feature_data()->mutable_lidar_sensor(0)->mutable_header()->mutable_sensor_id()->set_value(7);
    EXPECT_TRUE(da.SerializeAsString() == db.SerializeAsString()) << "frame " << k;
  }
  const osi3::SensorData d = parsed(b.back());
  EXPECT_DOUBLE_EQ(d.mounting_position().position().z(), 1.43);  // echoed: the mount that was used
  EXPECT_EQ(d.sensor_id().value(), 7u);                           // the virtual sensor's id
  EXPECT_GT(d.feature_data().lidar_sensor(0).detection_size(), 1000);
}

TEST(OsiConventions, FirstLidarViewWithAMountIsUsedWhenTheTopLevelOneIsAbsent) {
  osi3::SensorView v = scene_at(0), ref = scene_at(0);
  v.add_lidar_sensor_view();  // no view_configuration
  set_mount(*v.add_lidar_sensor_view()->mutable_view_configuration()->mutable_mounting_position(), 2.0, 1.2);
  set_mount(*v.add_lidar_sensor_view()->mutable_view_configuration()->mutable_mounting_position(), 3.0, 1.0);
  set_mount(*ref.mutable_mounting_position(), 2.0, 1.2);
  const std::string out = run_conventions_cli({v}, false)[0];
  EXPECT_TRUE(without_features(out) == without_features(run_conventions_cli({ref}, false)[0]));
  // One (empty, object-level model) feature list per detector, each with its own mount; the first
  // detector has none of its own and is the virtual sensor.
  const osi3::SensorData d = parsed(out);
  ASSERT_EQ(d.feature_data().lidar_sensor_size(), 3);
  const double x[3] = {2.0, 2.0, 3.0};
  for (int i = 0; i < 3; ++i)
    EXPECT_DOUBLE_EQ(d.feature_data().lidar_sensor(i).header().mounting_position().position().x(), x[i]) << i;
}

TEST(OsiConventions, TopLevelMountGovernsTheObjectsAndTheViewConfigurationsMountItsDetections) {
  // OSI: SensorView.mounting_position is the virtual sensor's mount, which governs the detected
  // objects; a view configuration's is one physical detector's, which governs its features.
  // One frame: the detectors are built on the first, which is where the mounts are read.
  osi3::SensorView both = scene_at(0), top_only = scene_at(0), lidar_only = scene_at(0);
  set_mount(*both.mutable_mounting_position(), 1.0, 1.43);
  set_mount(*both.add_lidar_sensor_view()->mutable_view_configuration()->mutable_mounting_position(), 2.5, 1.1, 0.3);
  set_mount(*top_only.mutable_mounting_position(), 1.0, 1.43);
  set_mount(*lidar_only.add_lidar_sensor_view()->mutable_view_configuration()->mutable_mounting_position(), 2.5, 1.1,
            0.3);
  const std::string b = run_conventions_cli({both}, true)[0], t = run_conventions_cli({top_only}, true)[0],
                    l = run_conventions_cli({lidar_only}, true)[0];
  EXPECT_TRUE(without_features(b) == without_features(t));
  EXPECT_FALSE(without_features(b) == without_features(l))
      << "the two mounts give the same objects, the rule is untested";
  const osi3::SensorData db = parsed(b), dt = parsed(t), dl = parsed(l);
  ASSERT_EQ(db.feature_data().lidar_sensor_size(), 1);
  EXPECT_TRUE(db.feature_data().lidar_sensor(0).SerializeAsString() ==
              dl.feature_data().lidar_sensor(0).SerializeAsString())
      << "the detections are not in the detector's own frame";
  EXPECT_FALSE(db.feature_data().lidar_sensor(0).SerializeAsString() ==
               dt.feature_data().lidar_sensor(0).SerializeAsString());
}

TEST(OsiConventions, SeveralLidarViewsAreAnsweredPerDetectorWithTheirOwnSensorIdAndMount) {
  // Two detectors of one virtual sensor (id 7): one at the virtual mount (id 70), one on the
  // right (id 71). Each gets its own lidar_sensor entry, the same as that detector alone.
  // One frame: the detectors are built on the first.
  osi3::SensorView two = scene_at(0), first = scene_at(0), second = scene_at(0);
  set_mount(*two.mutable_mounting_position(), 1.0, 1.43);
  auto* c0 = two.add_lidar_sensor_view()->mutable_view_configuration();
  c0->mutable_sensor_id()->set_value(70);
  auto* c1 = two.add_lidar_sensor_view()->mutable_view_configuration();
  c1->mutable_sensor_id()->set_value(71);
  set_mount(*c1->mutable_mounting_position(), 2.5, 1.1, -0.3);
  set_mount(*first.mutable_mounting_position(), 1.0, 1.43);
  set_mount(*second.mutable_mounting_position(), 2.5, 1.1, -0.3);
  const std::string b = run_conventions_cli({two}, true)[0], f = run_conventions_cli({first}, true)[0],
                    s = run_conventions_cli({second}, true)[0];
  const osi3::SensorData d = parsed(b), df = parsed(f), ds = parsed(s);
  EXPECT_EQ(d.sensor_id().value(), 7u);
  EXPECT_TRUE(without_features(b) == without_features(f));
  ASSERT_EQ(d.feature_data().lidar_sensor_size(), 2);
  const auto& l0 = d.feature_data().lidar_sensor(0);
  const auto& l1 = d.feature_data().lidar_sensor(1);
  EXPECT_EQ(l0.header().sensor_id().value(), 70u);
  EXPECT_EQ(l1.header().sensor_id().value(), 71u);
  EXPECT_DOUBLE_EQ(l1.header().mounting_position().orientation().yaw(), -0.3);
  ASSERT_GT(l1.detection_size(), 1000);
  ASSERT_EQ(l0.detection_size(), df.feature_data().lidar_sensor(0).detection_size());
  ASSERT_EQ(l1.detection_size(), ds.feature_data().lidar_sensor(0).detection_size());
  const auto same = [](const osi3::LidarDetection& a, const osi3::LidarDetection& b) {
    return a.SerializeAsString() == b.SerializeAsString();
  };
  for (int i = 0; i < l1.detection_size(); i += 97)
    EXPECT_TRUE(same(l1.detection(i), ds.feature_data().lidar_sensor(0).detection(i))) << i;
  for (int i = 0; i < l0.detection_size(); i += 97)
    EXPECT_TRUE(same(l0.detection(i), df.feature_data().lidar_sensor(0).detection(i))) << i;
}

TEST(OsiConventions, NoMountAnywhereAndANonFiniteLidarViewMountAreErrorsNamingTheField) {
  osi3::SensorView none = scene_at(0);
  none.add_lidar_sensor_view()->mutable_view_configuration()->mutable_sensor_id()->set_value(70);
  EXPECT_NE(error_of(none).find("hand: message 0: mounting_position: missing"), std::string::npos) << error_of(none);

  osi3::SensorView bad = scene_at(0);
  bad.add_lidar_sensor_view();
  set_mount(*bad.add_lidar_sensor_view()->mutable_view_configuration()->mutable_mounting_position(), NAN, 1.4);
  EXPECT_NE(error_of(bad).find("lidar_sensor_view[1].view_configuration.mounting_position: not finite"),
            std::string::npos)
      << error_of(bad);
}

TEST(OsiConventions, IdealModelReportsEveryVisibleObjectInFrameZeroWithTheTruthsMotion) {
  OsiRunner runner = make_runner(false);
  osi3::SensorView v = scene_at(0);
  set_mount(*v.mutable_mounting_position(), 1.0, 1.43);
  osi3::SensorData d;
  runner.step(v, 0, "hand", d);

  int visible = 0;
  for (const auto& o : runner.last_frame().sensor.objects) visible += o.visible_fraction > 0;
  EXPECT_EQ(visible, 2);  // the van and the pedestrian; the car is hidden behind the van
  std::map<std::uint64_t, const osi3::DetectedMovingObject*> by_truth;
  for (const auto& m : d.moving_object()) {
    ASSERT_EQ(m.header().ground_truth_id_size(), 1);
    EXPECT_EQ(m.header().measurement_state(), osi3::DetectedItemHeader::MEASUREMENT_STATE_MEASURED);
    by_truth[m.header().ground_truth_id(0).value()] = &m;
  }
  ASSERT_EQ(static_cast<int>(by_truth.size()), visible);
  ASSERT_TRUE(by_truth.count(11) && by_truth.count(13));
  const auto& van = by_truth[11]->base();
  EXPECT_NEAR(van.position().x(), 14.0, 1e-6);  // the truth, not a filter's estimate
  EXPECT_NEAR(van.velocity().x(), 0, 1e-9);
  const auto& ped = by_truth[13]->base();
  EXPECT_NEAR(ped.position().x(), 9.0, 1e-6);
  EXPECT_NEAR(ped.position().y(), 5.0, 1e-6);
  EXPECT_NEAR(ped.velocity().y(), -1.5, 1e-9);  // host at rest: relative = over ground
  EXPECT_NEAR(ped.acceleration().y(), -0.5, 1e-9);
}

TEST(OsiConventions, WithoutIdealTracksStillConfirmOnTheirSecondFrame) {
  // The default model keeps its tracker: frame 0 may hold the KPI model's false positives, but no
  // track of a real object yet.
  OsiRunner runner = make_runner(false, false);
  osi3::SensorData d;
  auto tracked = [&] {
    int n = 0;
    for (const auto& m : d.moving_object()) n += m.header().ground_truth_id_size() > 0;
    return n;
  };
  for (int k = 0; k < 2; ++k) {
    osi3::SensorView v = scene_at(0.1 * k);
    set_mount(*v.mutable_mounting_position(), 1.0, 1.43);
    runner.step(v, k, "hand", d);
    if (k == 0) {
      EXPECT_EQ(tracked(), 0);
    }
  }
  EXPECT_GT(tracked(), 0);
}

TEST(OsiConventions, SensorDataCarriesTheVersionWeImplement) {
  EXPECT_EQ(lidarsim::osi::kOsiVersion[0], 3u);
  EXPECT_EQ(lidarsim::osi::kOsiVersion[1], 8u);
  EXPECT_EQ(lidarsim::osi::kOsiVersion[2], 0u);
  OsiRunner runner = make_runner(true);
  osi3::SensorView v = scene_at(0);
  set_mount(*v.mutable_mounting_position(), 1.0, 1.43);
  osi3::SensorData d;
  runner.step(v, 0, "hand", d);
  for (const osi3::InterfaceVersion* iv : {&d.version(), &d.feature_data().version()}) {
    EXPECT_EQ(iv->version_major(), 3u);
    EXPECT_EQ(iv->version_minor(), 8u);
    EXPECT_EQ(iv->version_patch(), 0u);
  }
}

TEST(OsiConventions, FmuDeclaresTheSameVersionItWrites) {
  lidarsim::testing::TempDir dir;
  const fs::path fmu = fs::path(LIDARSIM_BINARY_DIR) / "lidarsim_osi.fmu";
  ASSERT_TRUE(fs::exists(fmu)) << fmu;
  ASSERT_EQ(std::system(("cd " + dir.path().string() + " && cmake -E tar xf " + fmu.string() +
                         " modelDescription.xml").c_str()),
            0);
  const std::string xml = read_bytes(dir / "modelDescription.xml");
  const std::string version = std::to_string(lidarsim::osi::kOsiVersion[0]) + "." +
                              std::to_string(lidarsim::osi::kOsiVersion[1]) + "." +
                              std::to_string(lidarsim::osi::kOsiVersion[2]);
  EXPECT_NE(xml.find("osi-version=\"" + version + "\""), std::string::npos) << xml;
  EXPECT_NE(xml.find("type=SensorView; version=" + version + "\""), std::string::npos);
  EXPECT_NE(xml.find("type=SensorData; version=" + version + "\""), std::string::npos);
}

TEST(OsiConventions, TraceWrittenByOurOsi350WriterStillDecodesAndRuns) {
  // tests/osi/data/demo_sv_osi_3.5.0.osi: `lidar-infer osi-trace --frames 2` of the build before
  // this change (main 0a62e203), which wrote version 3.5.0.
  const fs::path path = fs::path(LIDARSIM_SOURCE_DIR) / "tests/osi/data/demo_sv_osi_3.5.0.osi";
  std::ifstream in(path, std::ios::binary);
  ASSERT_TRUE(in) << path;
  lidarsim::osi::TraceReader reader(in, path.string());
  OsiRunner runner = make_runner(false);
  osi3::SensorView v;
  osi3::SensorData d;
  int n = 0;
  while (reader.next(v)) {
    EXPECT_EQ(v.version().version_minor(), 5u);
    runner.step(v, n, path.string(), d);
    EXPECT_EQ(d.version().version_minor(), 8u);
    EXPECT_EQ(d.timestamp().nanos(), v.timestamp().nanos());
    EXPECT_GT(d.moving_object_size(), 0) << "frame " << n;  // ideal: frame 0 too
    EXPECT_GT(d.lane_boundary_size(), 0) << "frame " << n;
    ++n;
  }
  EXPECT_EQ(n, 2);
}

TEST(OsiConventions, LidarInferOsiIdealReportsObjectsInItsFirstSensorData) {
  lidarsim::testing::TempDir dir;
  const fs::path exe = fs::path(LIDARSIM_BINARY_DIR) / "infer" / "lidar-infer";
  const fs::path in = dir / "in.osi", ideal = dir / "ideal.osi", plain = dir / "plain.osi", err = dir / "err.txt";
  auto run_cli = [&](const std::string& args) {
    const int rc = std::system((exe.string() + " " + args + " 2>" + err.string()).c_str());
    return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
  };
  ASSERT_EQ(run_cli("osi-trace --frames 1 --out " + in.string()), 0) << read_bytes(err);
  ASSERT_EQ(run_cli("osi --no-point-cloud --quiet --ideal --in " + in.string() + " --out " + ideal.string()), 0)
      << read_bytes(err);
  ASSERT_EQ(run_cli("osi --no-point-cloud --quiet --in " + in.string() + " --out " + plain.string()), 0) << read_bytes(err);
  auto tracked_in_first = [](const fs::path& p) {
    std::ifstream f(p, std::ios::binary);
    lidarsim::osi::TraceReader reader(f, p.string());
    osi3::SensorData d;
    EXPECT_TRUE(reader.next(d));
    int n = 0;
    for (const auto& m : d.moving_object()) n += m.header().ground_truth_id_size() > 0;
    return n;
  };
  EXPECT_GT(tracked_in_first(ideal), 0);
  EXPECT_EQ(tracked_in_first(plain), 0);
}
