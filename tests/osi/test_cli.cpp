// `lidar-infer osi-trace` and `lidar-infer osi` end to end: a scenario becomes a SensorView trace,
// the trace becomes one SensorData per frame, files and pipes give the same bytes, txth is text,
// a torn trace fails with the message index and leaves no output file behind.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "../data/temp_dir.h"
#include "osi/osi3_subset.pb.h"
#include "osi/trace.h"
#include "tests/support/file_bytes.h"

using lidarsim::testing::read_bytes;

namespace {

namespace fs = std::filesystem;

const fs::path kExe = fs::path(LIDARSIM_BINARY_DIR) / "infer" / "lidar-infer";

int run(const std::string& args, const fs::path& err) {
  const int rc = std::system((kExe.string() + " " + args + " 2>" + err.string()).c_str());
  return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}

}  // namespace

TEST(OsiCli, ScenarioTraceThroughLidarInferOsiGivesOneSensorDataPerFrame) {
  lidarsim::testing::TempDir dir;
  const fs::path in = dir / "in.osi", out = dir / "out.osi", err = dir / "err.txt";
  ASSERT_EQ(run("osi-trace --frames 4 --out " + in.string(), err), 0) << read_bytes(err);
  ASSERT_EQ(run("osi --in " + in.string() + " --out " + out.string() + " --threads 1", err), 0) << read_bytes(err);
  EXPECT_NE(read_bytes(err).find("4 frames:"), std::string::npos) << read_bytes(err);

  std::ifstream sv(in, std::ios::binary), sd(out, std::ios::binary);
  lidarsim::osi::TraceReader views(sv, in.string()), datas(sd, out.string());
  osi3::SensorView v;
  osi3::SensorData d;
  int n = 0;
  while (views.next(v)) {
    ASSERT_TRUE(datas.next(d)) << "frame " << n;
    EXPECT_EQ(d.timestamp().seconds(), v.timestamp().seconds());
    EXPECT_EQ(d.timestamp().nanos(), v.timestamp().nanos());
    EXPECT_EQ(d.sensor_id().value(), v.sensor_id().value());
    ASSERT_EQ(d.feature_data().lidar_sensor_size(), 1);
    EXPECT_GT(d.feature_data().lidar_sensor(0).detection_size(), 10000);
    for (const auto& m : d.moving_object())
      for (const auto& g : m.header().ground_truth_id()) EXPECT_NE(g.value(), v.host_vehicle_id().value());
    ++n;
  }
  EXPECT_EQ(n, 4);
  EXPECT_FALSE(datas.next(d));
  EXPECT_GT(d.moving_object_size(), 0);  // the last frame has confirmed tracks
}

TEST(OsiCli, StdinToStdoutGivesTheSameBytesAsFiles) {
  lidarsim::testing::TempDir dir;
  const fs::path in = dir / "in.osi", out = dir / "out.osi", piped = dir / "piped.osi", err = dir / "err.txt";
  ASSERT_EQ(run("osi-trace --frames 3 --out " + in.string(), err), 0) << read_bytes(err);
  ASSERT_EQ(run("osi --no-point-cloud --in " + in.string() + " --out " + out.string(), err), 0) << read_bytes(err);
  ASSERT_EQ(run("osi --no-point-cloud --in - --out - < " + in.string() + " > " + piped.string(), err), 0)
      << read_bytes(err);
  EXPECT_FALSE(read_bytes(out).empty());
  EXPECT_EQ(read_bytes(piped), read_bytes(out));
}

TEST(OsiCli, TxthOutputIsTheTextFormat) {
  lidarsim::testing::TempDir dir;
  const fs::path in = dir / "in.osi", out = dir / "out.txth", err = dir / "err.txt";
  ASSERT_EQ(run("osi-trace --frames 3 --out " + in.string(), err), 0) << read_bytes(err);
  ASSERT_EQ(run("osi --no-point-cloud --format txth --in " + in.string() + " --out " + out.string(), err), 0)
      << read_bytes(err);
  const std::string text = read_bytes(out);
  EXPECT_NE(text.find("version {\n  version_major: 3"), std::string::npos);
  EXPECT_NE(text.find("moving_object {"), std::string::npos);
}

TEST(OsiCli, TornTraceFailsNamingTheMessageAndWritesNoOutput) {
  lidarsim::testing::TempDir dir;
  const fs::path in = dir / "in.osi", torn = dir / "torn.osi", out = dir / "out.osi", err = dir / "err.txt";
  ASSERT_EQ(run("osi-trace --frames 3 --out " + in.string(), err), 0) << read_bytes(err);
  const std::string t = read_bytes(in);
  std::ofstream(torn, std::ios::binary) << t.substr(0, t.size() - 10);
  EXPECT_EQ(run("osi --no-point-cloud --in " + torn.string() + " --out " + out.string(), err), 1);
  EXPECT_NE(read_bytes(err).find("torn.osi: message 2: torn"), std::string::npos) << read_bytes(err);
  EXPECT_FALSE(fs::exists(out));
  for (const auto& e : fs::directory_iterator(dir.path()))
    EXPECT_EQ(e.path().filename().string().find("out.osi"), std::string::npos) << e.path();
}

TEST(OsiCli, BadFormatIsOneClearError) {
  lidarsim::testing::TempDir dir;
  const fs::path err = dir / "err.txt";
  EXPECT_NE(run("osi --in x.osi --out y.osi --format json", err), 0);
  EXPECT_NE(read_bytes(err).find("--format: must be binary or txth, got 'json'"), std::string::npos) << read_bytes(err);
}
