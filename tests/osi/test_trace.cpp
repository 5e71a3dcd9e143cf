// Binary OSI traces: messages come back as written; a torn length, a torn body, garbage and a
// SensorView without ground truth each give one error naming the message index.
#include <gtest/gtest.h>

#include <random>
#include <sstream>
#include <string>

#include "common/error.h"
#include "osi/osi3_subset.pb.h"
#include "osi/sensor_view.h"
#include "osi/trace.h"

namespace {

using lidarsim::osi::TraceFormat;
using lidarsim::osi::TraceReader;
using lidarsim::osi::TraceWriter;

std::string trace_of(int n) {
  std::ostringstream out;
  TraceWriter w(out, TraceFormat::Binary);
  for (int i = 0; i < n; ++i) {
    osi3::SensorView v;
    v.mutable_sensor_id()->set_value(static_cast<std::uint64_t>(100 + i));
    v.mutable_global_ground_truth()->mutable_host_vehicle_id()->set_value(1);
    w.write(v);
  }
  return out.str();
}

// The error message reading `trace` to its end, "" if none.
std::string read_error(const std::string& trace) {
  std::istringstream in(trace);
  TraceReader r(in, "t.osi");
  osi3::SensorView v;
  try {
    while (r.next(v)) {
    }
  } catch (const lidarsim::Error& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(OsiTrace, MessagesComeBackInOrderWithLittleEndianLengths) {
  const std::string t = trace_of(3);
  const auto first_length = static_cast<unsigned char>(t[0]) | static_cast<unsigned char>(t[1]) << 8;
  EXPECT_EQ(t[2], 0);
  EXPECT_EQ(t[3], 0);
  osi3::SensorView first;
  ASSERT_TRUE(first.ParseFromString(t.substr(4, first_length)));
  EXPECT_EQ(first.sensor_id().value(), 100u);

  std::istringstream in(t);
  TraceReader r(in, "t.osi");
  osi3::SensorView v;
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(r.next(v));
    EXPECT_EQ(r.index(), i);
    EXPECT_EQ(v.sensor_id().value(), static_cast<std::uint64_t>(100 + i));
  }
  EXPECT_FALSE(r.next(v));
  EXPECT_EQ(read_error(t), "");
}

TEST(OsiTrace, EmptyTraceEndsCleanly) {
  std::istringstream in("");
  TraceReader r(in, "t.osi");
  std::string bytes;
  EXPECT_FALSE(r.next(bytes));
}

TEST(OsiTrace, TornLengthFieldNamesTheMessage) {
  const std::string e = read_error(trace_of(3) + std::string("\x05\x00", 2));
  EXPECT_NE(e.find("t.osi: message 3: length field torn (2 of 4 bytes"), std::string::npos) << e;
}

TEST(OsiTrace, TornBodyNamesTheMessageAndTheMissingBytes) {
  const std::string t = trace_of(3);
  const std::string e = read_error(t.substr(0, t.size() - 2));
  EXPECT_NE(e.find("t.osi: message 2: torn"), std::string::npos) << e;
}

TEST(OsiTrace, TornBodyClaimingAGigabyteCostsOnlyWhatTheTraceHolds) {
  // 16 bytes of trace whose length field says 1 GiB - 1: an error, without a 1 GiB buffer.
  std::istringstream in(std::string("\xff\xff\xff\x3f", 4) + std::string(12, 'x'));
  TraceReader r(in, "t.osi");
  std::string bytes;
  EXPECT_THROW(r.next(bytes), lidarsim::Error);
  EXPECT_LT(bytes.capacity(), std::size_t{128} << 10);  // the first chunk, 64 KiB
}

TEST(OsiTrace, BodiesLargerThanTheReadChunksArriveWhole) {
  for (const std::size_t size : {std::size_t{0}, std::size_t{65535}, std::size_t{65537}, (std::size_t{3} << 20) + 1}) {
    std::string body(size, '\0');
    for (std::size_t i = 0; i < size; ++i) body[i] = static_cast<char>(i * 131 % 251);
    const auto n = static_cast<std::uint32_t>(size);
    const char header[4] = {static_cast<char>(n & 0xff), static_cast<char>(n >> 8 & 0xff), static_cast<char>(n >> 16 & 0xff),
                            static_cast<char>(n >> 24)};
    std::istringstream in(std::string(header, 4) + body);
    TraceReader r(in, "t.osi");
    std::string bytes;
    ASSERT_TRUE(r.next(bytes)) << size;
    EXPECT_TRUE(bytes == body) << size;
    EXPECT_FALSE(r.next(bytes));
  }
}

TEST(OsiTrace, MessageThatDoesNotParseNamesItsIndexAndType) {
  // A well-formed length followed by bytes that are no protobuf (field number 0 is invalid).
  const std::string bad = std::string("\x03\x00\x00\x00", 4) + std::string("\x00\x00\x00", 3);
  const std::string e = read_error(trace_of(2) + bad);
  EXPECT_NE(e.find("t.osi: message 2: does not parse as osi3.SensorView"), std::string::npos) << e;
}

TEST(OsiTrace, GarbageGivesOneErrorAtMessageZero) {
  std::mt19937 rng(7);
  std::string garbage(4096, '\0');
  for (auto& c : garbage) c = static_cast<char>(rng());
  garbage[3] = '\x7f';  // a length far beyond anything a trace holds
  const std::string e = read_error(garbage);
  EXPECT_NE(e.find("t.osi: message 0: length field says"), std::string::npos) << e;
}

TEST(OsiTrace, SensorViewWithoutGroundTruthIsRejectedWithItsIndex) {
  osi3::SensorView v;
  v.mutable_host_vehicle_id()->set_value(1);
  lidarsim::osi::IdMap ids;
  lidarsim::osi::SceneFrame scene;
  try {
    lidarsim::osi::scene_from_sensor_view(v, 4, "t.osi", ids, scene);
    FAIL() << "no error";
  } catch (const lidarsim::Error& e) {
    EXPECT_NE(std::string(e.what()).find("t.osi: message 4: global_ground_truth: missing"), std::string::npos)
        << e.what();
  }
}

TEST(OsiTrace, TextFormatWritesOneReadableBlockPerMessage) {
  std::ostringstream out;
  TraceWriter w(out, TraceFormat::Text);
  osi3::SensorView v;
  v.mutable_sensor_id()->set_value(9);
  w.write(v);
  w.write(v);
  EXPECT_EQ(out.str(), "sensor_id {\n  value: 9\n}\n\nsensor_id {\n  value: 9\n}\n\n");
}
