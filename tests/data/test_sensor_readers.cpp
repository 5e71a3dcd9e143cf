// Readers of other sensors, checked on the real files in ../shared/data against the facts in
// their SOURCE.md (counted there by an independent parser) and the vendors' specifications.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <numbers>
#include <set>

#include "common/error.h"
#include "data/nuscenes.h"
#include "data/ouster.h"
#include "data/rellis3d.h"
#include "pgm/materials.h"
#include "tests/data/temp_dir.h"
#include "tests/support/shared_data.h"

using namespace lidarsim;
using lidarsim::testing::TempDir;
using lidarsim::testing::error_of;

namespace {
double median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}
double elevation_deg(const pgm::Point& p) {
  return std::atan2(p.z, std::hypot(p.x, p.y)) * 180.0 / std::numbers::pi;
}
}  // namespace

TEST(NuscenesReal, SampleHas34688PointsOn32RingsTopRingAtHdl32eSpecElevation) {
  LIDARSIM_REQUIRE_SHARED_DATA(dir, "nuscenes-sample-frame");
  const auto files = data::list_nuscenes(dir);
  ASSERT_EQ(files.size(), 1u);
  EXPECT_EQ(files[0].log, "n015-2018-07-24-11-22-45+0800");
  EXPECT_EQ(files[0].timestamp, "1532402927647951");
  const auto points = data::read_nuscenes_pcd_bin(files[0].path);
  ASSERT_EQ(points.size(), 34688u);  // SOURCE.md
  std::vector<std::vector<double>> el(32);
  double max_range = 0;
  float max_intensity = 0;
  for (const auto& p : points) {
    ASSERT_GE(p.ring, 0);
    ASSERT_LT(p.ring, 32);
    el[p.ring].push_back(elevation_deg(p));
    max_range = std::max(max_range, std::sqrt(double(p.x) * p.x + double(p.y) * p.y + double(p.z) * p.z));
    max_intensity = std::max(max_intensity, p.intensity);
  }
  for (const auto& e : el) EXPECT_FALSE(e.empty());  // 32 distinct rings
  // HDL-32E data sheet: +10.67 deg to -30.67 deg; our row 0 is the top beam.
  EXPECT_NEAR(median(el[0]), 10.67, 0.3);
  EXPECT_NEAR(median(el[31]), -30.67, 0.3);
  EXPECT_NEAR(max_range, 102.9, 0.1);  // SOURCE.md
  EXPECT_LE(max_intensity, 1.f);
  EXPECT_GT(max_intensity, 0.5f);  // 0-255 scaled by 1/255, not clipped to nothing
}

TEST(Nuscenes, TruncatedFileAndRingOutOfRangeNameTheFileAndField) {
  TempDir dir;
  lidarsim::testing::write_binary(dir / "a.pcd.bin", std::vector<float>{1, 2, 3, 4});
  EXPECT_NE(error_of([&] { data::read_nuscenes_pcd_bin(dir / "a.pcd.bin"); }).find("a.pcd.bin: size"), std::string::npos);
  lidarsim::testing::write_binary(dir / "b.pcd.bin", std::vector<float>{1, 2, 3, 4, 32});
  EXPECT_NE(error_of([&] { data::read_nuscenes_pcd_bin(dir / "b.pcd.bin"); }).find("point 0 ring"), std::string::npos);
}

TEST(Rellis3dReal, ReturnsClassesAndUnmappedPuddleMatchSourceCounts) {
  LIDARSIM_REQUIRE_SHARED_DATA(dir, "rellis3d-os1-sample");
  const auto table = data::read_class_table(lidarsim::testing::source_dir() / "data/ontologies/rellis3d.csv");
  const auto files = data::list_rellis3d(dir);
  ASSERT_EQ(files.size(), 1u);
  ASSERT_TRUE(files[0].label.has_value());
  ASSERT_TRUE(files[0].ply.has_value());
  const auto scan = data::read_rellis3d_scan(files[0], table);
  EXPECT_EQ(scan.cells, 131072u);           // 2048 x 64
  EXPECT_EQ(scan.points.size(), 77708u);    // returns, SOURCE.md
  EXPECT_TRUE(scan.reflectivity);
  std::size_t terrain = 0, person = 0;
  std::vector<double> range;
  std::set<int> rings;
  for (const auto& p : scan.points) {
    terrain += p.class_id == pgm::cls::terrain;
    person += p.class_id == pgm::cls::person;
    range.push_back(std::sqrt(double(p.x) * p.x + double(p.y) * p.y + double(p.z) * p.z));
    rings.insert(p.ring);
  }
  EXPECT_EQ(terrain, 18040u + 100u);  // grass + mud
  EXPECT_EQ(person, 1310u);
  ASSERT_EQ(scan.unmapped.size(), 1u);  // puddle has no class of ours: reported, not guessed
  EXPECT_EQ(scan.unmapped.at("puddle"), 1269u);
  EXPECT_NEAR(median(range), 7.3, 0.1);
  EXPECT_EQ(rings.size(), 64u);
  // Intensity is the PLY's reflectivity on a fixed scale: spread out, saturating only rarely.
  std::size_t saturated = 0;
  std::vector<double> intensity;
  for (const auto& p : scan.points) {
    saturated += p.intensity >= 1.f;
    intensity.push_back(p.intensity);
  }
  EXPECT_LT(saturated, scan.points.size() * 3 / 100);  // 2.6 %: retro-reflectors and the brightest leaves
  EXPECT_NEAR(median(intensity), 1538.0 / data::kRellisReflectivityScale, 0.01);
}

TEST(ClassTable, UnknownClassNameAndRepeatedIdAreNamedWithTheLine) {
  TempDir dir;
  { std::ofstream(dir / "t.csv") << "# comment\n1,dirt,terrain\n2,lava,molten_rock\n"; }
  EXPECT_NE(error_of([&] { data::read_class_table(dir / "t.csv"); }).find("t.csv: line 3 class"), std::string::npos);
  { std::ofstream(dir / "u.csv") << "1,dirt,terrain\n1,mud,terrain\n"; }
  EXPECT_NE(error_of([&] { data::read_class_table(dir / "u.csv"); }).find("line 2 id"), std::string::npos);
}

namespace {
struct OusterFacts {
  const char* pcap;
  std::size_t frames;
  int rows;
  long valid;
  double max_range, median_range;
};
}  // namespace

TEST(OusterReal, EveryProfileDecodesToTheSourceCounts) {
  LIDARSIM_REQUIRE_SHARED_DATA(dir, "ouster-sample-pcaps");
  // SOURCE.md's table: frames, beams, valid pixels, max / median range.
  const OusterFacts facts[] = {
      {"OS-2-128-U1_v2.3.0_1024x10.pcap", 1, 128, 119682, 331.6, 13.5},       // RNG19_RFL8_SIG16_NIR16
      {"OS-0-128-U1_v2.3.0_1024x10.pcap", 1, 128, 97299, 63.0, 7.5},          // RNG15_RFL8_NIR8
      {"OS-1-32-G_v2.1.1_1024x10.pcap", 1, 32, 27310, 204.3, 13.1},           // legacy
      {"OS-1-128_v2.3.0_1024x10_lb_n3.pcap", 3, 128, 322536, 65.5, 11.3}};  // RNG15_RFL8_NIR8
  for (const auto& f : facts) {
    SCOPED_TRACE(f.pcap);
    const auto meta = data::read_ouster_metadata(data::ouster_metadata_for(dir / f.pcap));
    const auto frames = data::read_ouster_pcap(dir / f.pcap, meta);
    ASSERT_EQ(frames.size(), f.frames);
    long valid = 0;
    std::vector<double> range;
    for (const auto& fr : frames) {
      EXPECT_EQ(fr.rows, f.rows);
      EXPECT_EQ(fr.valid_columns(), 1024);
      for (auto r : fr.range_mm)
        if (r > 0) ++valid, range.push_back(r / 1000.0);
    }
    EXPECT_EQ(valid, f.valid);
    // SOURCE.md's maxima for the RNG15 files (63.0, 65.5 m) are what a 13-bit range field gives
    // (65.5 m = 8191 x 8 mm); the profile's field is 15 bits, and 37 OS-0 pixels lie beyond
    // 63 m. Counts and medians agree either way; the maxima are checked where both agree.
    if (f.max_range > 66) {
      EXPECT_NEAR(*std::max_element(range.begin(), range.end()), f.max_range, 0.051);
    }
    EXPECT_NEAR(median(range), f.median_range, 0.06);  // SOURCE.md rounds to 0.1 m
    // The point cloud puts every return at its measured range (to the beam-origin offset) and
    // in its beam's elevation.
    const auto points = data::ouster_points(frames[0], meta);
    std::size_t returns0 = 0;
    for (auto r : frames[0].range_mm) returns0 += r > 0;
    ASSERT_EQ(points.size(), returns0);
    const auto layout = meta.layout();
    for (std::size_t i = 0; i < points.size(); i += 997) {
      const auto& p = points[i];
      const double expected = layout.elevations_rad[p.ring] * 180.0 / std::numbers::pi;
      const double z_offset = meta.lidar_to_sensor[11] / 1000.0;
      const double el = std::atan2(p.z - z_offset, std::hypot(p.x, p.y)) * 180.0 / std::numbers::pi;
      if (std::hypot(p.x, p.y) > 20) {  // nearer, the beam-origin offset shifts the elevation
        EXPECT_NEAR(el, expected, 0.05);
      }
    }
  }
  const auto lb = data::read_ouster_pcap(dir / facts[3].pcap, data::read_ouster_metadata(data::ouster_metadata_for(dir / facts[3].pcap)));
  EXPECT_EQ(lb[0].frame_id, 1795u);  // SOURCE.md: consecutive ids 1795-1797
  EXPECT_EQ(lb[2].frame_id, 1797u);
}

TEST(OusterReal, MetadataOfAnotherSensorIsRefusedNamingThePacketSize) {
  LIDARSIM_REQUIRE_SHARED_DATA(dir, "ouster-sample-pcaps");
  const auto meta = data::read_ouster_metadata(dir / "OS-1-32-G_v2.1.1_1024x10.json");
  const std::string msg = error_of([&] { data::read_ouster_pcap(dir / "OS-2-128-U1_v2.3.0_1024x10.pcap", meta); });
  EXPECT_NE(msg.find("lidar packet of 24832 bytes"), std::string::npos) << msg;
}

// A frame id that changes every few columns cost a whole frame each (rows x columns cells): a
// 64 KB fuzz input made hundreds of MB. A frame between the first and last now needs half its
// columns; one lidar packet of the middle frame relabelled cuts that frame to 6 packets.
TEST(OusterReal, AFrameCutShortBetweenOthersIsAnErrorNamingItsIds) {
  LIDARSIM_REQUIRE_SHARED_DATA(dir, "ouster-sample-pcaps");
  const std::filesystem::path source = dir / "OS-1-128_v2.3.0_1024x10_lb_n3.pcap";  // frames 1795-1797, 64 packets each
  const auto meta = data::read_ouster_metadata(data::ouster_metadata_for(source));
  std::ifstream in(source, std::ios::binary);
  std::string bytes{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  int lidar = 0;
  for (std::size_t at = 24; at + 16 <= bytes.size();) {  // pcap records: 16-byte header, then the packet
    std::uint32_t caplen;
    std::memcpy(&caplen, bytes.data() + at + 8, 4);
    const std::size_t packet = at + 16, udp = packet + 14 + 20;
    const int port = static_cast<unsigned char>(bytes[udp + 2]) << 8 | static_cast<unsigned char>(bytes[udp + 3]);
    if (port == meta.udp_port_lidar && lidar++ == 70) {
      bytes[udp + 8 + 2] = static_cast<char>(1800 & 0xff);  // packet header: frame id u16 at byte 2
      bytes[udp + 8 + 3] = static_cast<char>(1800 >> 8);
    }
    at = packet + caplen;
  }
  ASSERT_EQ(lidar, 192);
  TempDir tmp;
  { std::ofstream(tmp / "relabelled.pcap", std::ios::binary) << bytes; }
  const std::string msg = error_of([&] { data::read_ouster_pcap(tmp / "relabelled.pcap", meta); });
  EXPECT_NE(msg.find("relabelled.pcap: record "), std::string::npos) << msg;
  EXPECT_NE(msg.find("frame 1796 ends after 96 of its 1024 columns, between frames 1795 and 1800"), std::string::npos) << msg;
}
