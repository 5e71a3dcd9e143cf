// Every lidar of a car in one process: several instances of lidarsim_osi.fmu,
// each with its own beam layout (the `sensor` parameter, a data/sensors/ layout) and its own
// SensorView (mount, sensor_id), give the same SensorData bytes when each runs alone, when they
// step one after the other, and when they step at the same time in threads of their own. The
// model keeps nothing process-wide that one instance's step could change under another's
// (nn/conv_settings.h, nn/weight_cache.h); a shared scratch buffer makes the threaded run differ
// or crash. tests/osi/test_fmu.cpp covers one instance as an importer drives it.
#include <dlfcn.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdarg>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "unpacked_fmu.h"
#include "infer/fmu/fmi2.h"
#include "osi/osi3_subset.pb.h"
#include "osi/scenario_trace.h"
#include "sensor/scenario.h"

namespace {

namespace fs = std::filesystem;

constexpr int kFrames = 2;

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

std::string xml_attribute(const std::string& xml, const std::string& name) {
  const auto at = xml.find(" " + name + "=\"");
  if (at == std::string::npos) return "";
  const auto start = at + name.size() + 3;
  return xml.substr(start, xml.find('"', start) - start);
}

// One lidar of the car: its layout, mount (host vehicle frame) and id.
struct Lidar {
  const char* layout;
  double x, y, z, yaw;
  std::uint64_t id;
};
const Lidar kLidars[] = {{"os1-32", 1.2, 0.0, 1.9, 0.0, 31}, {"hdl32e-nuscenes", 3.6, -0.7, 0.6, -0.6, 32}};
constexpr int kLidarCount = sizeof kLidars / sizeof kLidars[0];

// The unpacked FMU and its functions, shared by every instance.
class Fmu {
 public:
  explicit Fmu(const fs::path& dir) {
    if (dir.empty()) return;
    xml = slurp(dir / "modelDescription.xml");
    guid = xml_attribute(xml, "guid");
    resources = "file://" + fs::absolute(dir / "resources").string();
    lib = dlopen((dir / "binaries" / "linux64" / "lidarsim_osi.so").c_str(), RTLD_NOW | RTLD_LOCAL);
    if (!lib) return;
    instantiate = sym<fmi2InstantiateTYPE>("fmi2Instantiate");
    set_string = sym<fmi2SetStringTYPE>("fmi2SetString");
    enter = sym<fmi2EnterInitializationModeTYPE>("fmi2EnterInitializationMode");
    exit_init = sym<fmi2ExitInitializationModeTYPE>("fmi2ExitInitializationMode");
    set_int = sym<fmi2SetIntegerTYPE>("fmi2SetInteger");
    get_int = sym<fmi2GetIntegerTYPE>("fmi2GetInteger");
    do_step = sym<fmi2DoStepTYPE>("fmi2DoStep");
    free_instance = sym<fmi2FreeInstanceTYPE>("fmi2FreeInstance");
  }
  ~Fmu() {
    if (lib) dlclose(lib);
  }
  bool ok() const { return lib && instantiate && set_string && exit_init && do_step && free_instance; }

  std::string xml, guid, resources;
  void* lib = nullptr;
  fmi2InstantiateTYPE* instantiate = nullptr;
  fmi2SetStringTYPE* set_string = nullptr;
  fmi2EnterInitializationModeTYPE* enter = nullptr;
  fmi2ExitInitializationModeTYPE* exit_init = nullptr;
  fmi2SetIntegerTYPE* set_int = nullptr;
  fmi2GetIntegerTYPE* get_int = nullptr;
  fmi2DoStepTYPE* do_step = nullptr;
  fmi2FreeInstanceTYPE* free_instance = nullptr;

 private:
  template <typename F>
  F* sym(const char* name) {
    return reinterpret_cast<F*>(dlsym(lib, name));
  }
};

// The SensorViews of one lidar: the demo scenario's frames with that lidar's mount and id.
std::vector<std::string> views_of(const Lidar& l) {
  const auto scenario =
      lidarsim::sensor::read_scenario(std::string(LIDARSIM_SOURCE_DIR) + "/data/scenarios/demo_urban.json");
  std::vector<std::string> out;
  for (int k = 0; k < kFrames; ++k) {
    osi3::SensorView v;
    lidarsim::osi::sensor_view_from_scenario(scenario, scenario.frame_time(k), v);
    v.mutable_sensor_id()->set_value(l.id);
    auto* m = v.mutable_mounting_position();
    m->mutable_position()->set_x(l.x);
    m->mutable_position()->set_y(l.y);
    m->mutable_position()->set_z(l.z);
    m->mutable_orientation()->set_yaw(l.yaw);
    out.push_back(v.SerializeAsString());
  }
  return out;
}

// One FMU instance for lidar `l`, initialised with its layout.
class Instance {
 public:
  Instance(const Fmu& fmu, const Lidar& l) : fmu_(fmu) {
    fmi2CallbackFunctions callbacks{};
    c_ = fmu.instantiate(l.layout, fmi2CoSimulation, fmu.guid.c_str(), fmu.resources.c_str(), &callbacks, 0, 0);
    if (!c_) return;
    const fmi2ValueReference sensor_vr = 6;
    const fmi2String layout = l.layout;
    ok_ = fmu.set_string(c_, &sensor_vr, 1, &layout) == fmi2OK && fmu.enter(c_) == fmi2OK &&
          fmu.exit_init(c_) == fmi2OK;
  }
  ~Instance() {
    if (c_) fmu_.free_instance(c_);
  }
  bool ok() const { return ok_; }

  // One fmi2DoStep on `view`; the SensorData bytes (empty on an error).
  std::string step(const std::string& view, int k) {
    const auto address = reinterpret_cast<std::uintptr_t>(view.data());
    const fmi2ValueReference in_vr[3] = {0, 1, 2}, out_vr[3] = {3, 4, 5};
    const fmi2Integer in[3] = {static_cast<fmi2Integer>(static_cast<std::uint32_t>(address & 0xffffffffu)),
                               static_cast<fmi2Integer>(static_cast<std::uint32_t>(std::uint64_t(address) >> 32)),
                               static_cast<fmi2Integer>(view.size())};
    fmi2Integer out[3] = {0, 0, 0};
    if (fmu_.set_int(c_, in_vr, 3, in) != fmi2OK || fmu_.do_step(c_, 0.1 * k, 0.1, 1) != fmi2OK ||
        fmu_.get_int(c_, out_vr, 3, out) != fmi2OK)
      return "";
    const auto out_address = static_cast<std::uintptr_t>(static_cast<std::uint32_t>(out[0])) |
                             static_cast<std::uintptr_t>(static_cast<std::uint32_t>(out[1])) << 32;
    return std::string(reinterpret_cast<const char*>(out_address), static_cast<std::size_t>(out[2]));
  }

 private:
  const Fmu& fmu_;
  fmi2Component c_ = nullptr;
  bool ok_ = false;
};

using Outputs = std::vector<std::vector<std::string>>;  // [lidar][frame]

// Lidar i on fmus[i], all lidars' frames stepped one after the other (frame by frame, lidar by
// lidar: the instances alternate) or each lidar in a thread of its own.
Outputs run_in_turn(const std::vector<const Fmu*>& fmus, const Outputs& views) {
  Outputs out(kLidarCount, std::vector<std::string>(kFrames));
  std::vector<std::unique_ptr<Instance>> insts;
  for (int i = 0; i < kLidarCount; ++i) insts.push_back(std::make_unique<Instance>(*fmus[i], kLidars[i]));
  for (int k = 0; k < kFrames; ++k)
    for (int i = 0; i < kLidarCount; ++i) out[i][k] = insts[i]->step(views[i][k], k);
  return out;
}
Outputs run_threaded(const std::vector<const Fmu*>& fmus, const Outputs& views) {
  Outputs out(kLidarCount, std::vector<std::string>(kFrames));
  std::vector<std::unique_ptr<Instance>> insts;
  for (int i = 0; i < kLidarCount; ++i) insts.push_back(std::make_unique<Instance>(*fmus[i], kLidars[i]));
  std::vector<std::thread> threads;
  for (int i = 0; i < kLidarCount; ++i)
    threads.emplace_back([&, i] {
      for (int k = 0; k < kFrames; ++k) out[i][k] = insts[i]->step(views[i][k], k);
    });
  for (std::thread& t : threads) t.join();
  return out;
}

void expect_same(const Outputs& got, const Outputs& alone, const char* how) {
  for (int i = 0; i < kLidarCount; ++i)
    for (int k = 0; k < kFrames; ++k) {
      ASSERT_FALSE(alone[i][k].empty()) << kLidars[i].layout << " frame " << k;
      EXPECT_TRUE(got[i][k] == alone[i][k]) << kLidars[i].layout << " frame " << k << ": " << how;
    }
}

std::string g_logged;
void multi_logger(fmi2ComponentEnvironment, fmi2String, fmi2Status, fmi2String, fmi2String message, ...) {
  char text[2048];
  va_list args;
  va_start(args, message);
  std::vsnprintf(text, sizeof text, message, args);
  va_end(args);
  g_logged += text;
}

}  // namespace

TEST(OsiFmuMulti, OneInstancePerLidarGivesTheSameBytesAloneInTurnAndInParallelThreads) {
  const Fmu fmu(lidarsim::testing::unpacked_fmu());
  ASSERT_TRUE(fmu.ok()) << "cannot unpack or load " << LIDARSIM_BINARY_DIR << "/lidarsim_osi.fmu";
  // Declared only because it holds (the threaded run below).
  EXPECT_EQ(xml_attribute(fmu.xml, "canBeInstantiatedOnlyOncePerProcess"), "false");
  Outputs views(kLidarCount);
  for (int i = 0; i < kLidarCount; ++i) views[i] = views_of(kLidars[i]);

  Outputs alone(kLidarCount, std::vector<std::string>(kFrames));
  for (int i = 0; i < kLidarCount; ++i) {
    Instance inst(fmu, kLidars[i]);
    ASSERT_TRUE(inst.ok()) << kLidars[i].layout;
    for (int k = 0; k < kFrames; ++k) alone[i][k] = inst.step(views[i][k], k);
  }
  // Each layout is the one asked for (rows of the grid: elevation angles of the detections), and
  // each lidar's output is its own.
  for (int i = 0; i < kLidarCount; ++i) {
    osi3::SensorData d;
    ASSERT_TRUE(d.ParseFromString(alone[i][kFrames - 1])) << kLidars[i].layout;
    EXPECT_EQ(d.sensor_id().value(), kLidars[i].id);
    ASSERT_EQ(d.feature_data().lidar_sensor_size(), 1);
    EXPECT_GT(d.feature_data().lidar_sensor(0).detection_size(), 5000) << kLidars[i].layout;
    std::vector<double> elevations;
    for (const auto& det : d.feature_data().lidar_sensor(0).detection())
      elevations.push_back(det.position().elevation());
    std::sort(elevations.begin(), elevations.end());
    EXPECT_LE(std::unique(elevations.begin(), elevations.end()) - elevations.begin(), 32) << kLidars[i].layout;
  }
  EXPECT_NE(alone[0][kFrames - 1], alone[1][kFrames - 1]);

  expect_same(run_in_turn({&fmu, &fmu}, views), alone, "in turn");
  expect_same(run_threaded({&fmu, &fmu}, views), alone, "in parallel threads");
}

// An importer that unpacks every instance into a folder of its own loads two copies of the
// libraries (two paths, two files: two dlopen'ed objects with their own static state). Each copy
// must run as if it were alone, whether the copies' instances alternate or run in two threads:
// nothing may be registered process-wide (the libprotobuf-linked model aborted here, registering
// its schema a second time) and no symbol of one copy may bind to the other's (only fmi2* and
// lidarsim_osi_model_* are exported; infer/fmu/*exports.map).
TEST(OsiFmuMulti, TwoUnpackedCopiesInOneProcessGiveTheSameBytesAlternatelyAndInTwoThreads) {
  const Fmu a(lidarsim::testing::unpacked_fmu()), b(lidarsim::testing::unpacked_fmu_copy());
  ASSERT_TRUE(a.ok() && b.ok()) << "cannot unpack or load " << LIDARSIM_BINARY_DIR << "/lidarsim_osi.fmu twice";
  ASSERT_NE(a.lib, b.lib) << "the second folder's library is the first one again";
  Outputs views(kLidarCount);
  for (int i = 0; i < kLidarCount; ++i) views[i] = views_of(kLidars[i]);
  // Each lidar alone on its copy, the other copy loaded but idle.
  Outputs alone(kLidarCount, std::vector<std::string>(kFrames));
  const Fmu* copies[kLidarCount] = {&a, &b};
  for (int i = 0; i < kLidarCount; ++i) {
    Instance inst(*copies[i], kLidars[i]);
    ASSERT_TRUE(inst.ok()) << kLidars[i].layout;
    for (int k = 0; k < kFrames; ++k) alone[i][k] = inst.step(views[i][k], k);
  }
  expect_same(run_in_turn({&a, &b}, views), alone, "two copies in turn");
  expect_same(run_threaded({&a, &b}, views), alone, "two copies in two threads");
  // And the copies compute the same model: lidar 0 on the second copy as on the first.
  Instance on_b(b, kLidars[0]);
  ASSERT_TRUE(on_b.ok());
  EXPECT_TRUE(on_b.step(views[0][0], 0) == alone[0][0]) << "the second copy differs from the first";
}

TEST(OsiFmuMulti, UnknownSensorLayoutFailsInitializationNamingTheLayouts) {
  const Fmu fmu(lidarsim::testing::unpacked_fmu());
  ASSERT_TRUE(fmu.ok());
  fmi2CallbackFunctions callbacks{};
  callbacks.logger = multi_logger;
  g_logged.clear();
  fmi2Component c = fmu.instantiate("x", fmi2CoSimulation, fmu.guid.c_str(), fmu.resources.c_str(), &callbacks, 0, 0);
  ASSERT_NE(c, nullptr);
  const fmi2ValueReference vr = 6;
  const fmi2String bad = "no-such-lidar";
  ASSERT_EQ(fmu.set_string(c, &vr, 1, &bad), fmi2OK);
  EXPECT_EQ(fmu.exit_init(c), fmi2Error);
  EXPECT_NE(g_logged.find("sensor: no layout \"no-such-lidar\""), std::string::npos) << g_logged;
  EXPECT_NE(g_logged.find("os1-64-rellis3d"), std::string::npos) << g_logged;  // the bundled ones are listed
  fmu.free_instance(c);
}
