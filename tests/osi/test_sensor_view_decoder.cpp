// The hand-written SensorView decoder (osi/sensor_view_decoder.h) against libprotobuf's parse
// (tests/osi/sensor_view_oracle.h): the bundled trace, the osi_trace fuzz regressions, random
// SensorViews with every field present or not, unknown fields of every wire type (groups nested,
// known field numbers with another wire type, enum values outside their enum) and repeated
// submessages merged; every truncation and random byte changes of them. Both ways accept the same
// messages and give the same fields and echoed bytes; refusals are one error naming the field.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "common/error.h"
#include "osi/osi3_subset.pb.h"
#include "osi/sensor_view_decoder.h"
#include "osi/trace.h"
#include "tests/osi/sensor_view_oracle.h"

namespace {

namespace fs = std::filesystem;
using namespace std::string_literals;  // "\x00"s keeps its zero bytes
using lidarsim::osi::oracle::compare_with_libprotobuf;
using google::protobuf::UnknownFieldSet;

class RandomView {
 public:
  explicit RandomView(unsigned seed) : rng_(seed) {}
  bool coin(double p = 0.5) { return std::bernoulli_distribution(p)(rng_); }
  int integer(int lo, int hi) { return std::uniform_int_distribution<int>(lo, hi)(rng_); }
  double real() { return coin(0.05) ? -0.0 : std::uniform_real_distribution<double>(-1e3, 1e3)(rng_); }
  // Values of every varint length, 1 to 10 bytes.
  std::uint64_t id() { return std::uniform_int_distribution<std::uint64_t>()(rng_) >> integer(0, 63); }
  std::mt19937_64& rng() { return rng_; }

 private:
  std::mt19937_64 rng_;
};

// Unknown fields of every wire type, sometimes on a known field number (so with another wire type
// than the schema's: libprotobuf keeps them as unknown) and sometimes nested in groups.
void add_unknown(RandomView& d, UnknownFieldSet& u, int depth = 0) {
  const int n = d.coin(0.7) ? 0 : d.integer(1, 3);
  for (int i = 0; i < n; ++i) {
    const int field = d.coin(0.3) ? d.integer(1, 9) : d.integer(10, 3000);
    switch (d.integer(0, 4)) {
      case 0: u.AddVarint(field, d.id()); break;
      case 1: u.AddFixed64(field, d.id()); break;
      case 2: u.AddFixed32(field, static_cast<std::uint32_t>(d.id())); break;
      case 3: u.AddLengthDelimited(field, std::string(static_cast<std::size_t>(d.integer(0, 5)), 'x')); break;
      default:
        if (depth < 3) add_unknown(d, *u.AddGroup(field), depth + 1);
        else u.AddVarint(field, 1);
    }
  }
}

template <class M>
void maybe_unknown(RandomView& d, M& m) {
  add_unknown(d, *m.mutable_unknown_fields());
}

void vector3d(RandomView& d, osi3::Vector3d& v) {
  if (d.coin(0.8)) v.set_x(d.real());
  if (d.coin(0.8)) v.set_y(d.real());
  if (d.coin(0.8)) v.set_z(d.real());
  maybe_unknown(d, v);
}

void orientation(RandomView& d, osi3::Orientation3d& o) {
  if (d.coin(0.8)) o.set_roll(d.real());
  if (d.coin(0.8)) o.set_pitch(d.real());
  if (d.coin(0.8)) o.set_yaw(d.real());
  maybe_unknown(d, o);
}

void mount(RandomView& d, osi3::MountingPosition& m) {
  if (d.coin(0.8)) vector3d(d, *m.mutable_position());
  if (d.coin(0.8)) orientation(d, *m.mutable_orientation());
  maybe_unknown(d, m);
}

void identifier(RandomView& d, osi3::Identifier& id) {
  if (d.coin(0.9)) id.set_value(d.id());
  maybe_unknown(d, id);
}

void timestamp(RandomView& d, osi3::Timestamp& t) {
  const auto seconds = static_cast<std::int64_t>(d.id() >> 1);
  if (d.coin(0.9)) t.set_seconds(d.coin(0.2) ? -seconds : seconds);
  if (d.coin(0.9)) t.set_nanos(static_cast<std::uint32_t>(d.id()));
  maybe_unknown(d, t);
}

// The fields BaseMoving and BaseStationary share: dimension, position, orientation.
template <class Base>
void random_box(RandomView& d, Base& b) {
  if (d.coin(0.9)) {
    b.mutable_dimension()->set_length(d.real());
    if (d.coin(0.9)) b.mutable_dimension()->set_width(d.real());
    b.mutable_dimension()->set_height(d.real());
  }
  if (d.coin(0.9)) vector3d(d, *b.mutable_position());
  if (d.coin(0.8)) orientation(d, *b.mutable_orientation());
}

void moving_object(RandomView& d, osi3::MovingObject& o) {
  if (d.coin(0.9)) identifier(d, *o.mutable_id());
  if (d.coin(0.9)) {
    auto& b = *o.mutable_base();
    random_box(d, b);
    if (d.coin(0.5)) vector3d(d, *b.mutable_velocity());
    if (d.coin(0.5)) vector3d(d, *b.mutable_acceleration());
    if (d.coin(0.2)) orientation(d, *b.mutable_orientation_rate());
    maybe_unknown(d, b);
  }
  if (d.coin(0.8)) o.set_type(static_cast<osi3::MovingObject::Type>(d.integer(0, 4)));
  if (d.coin(0.1)) o.mutable_unknown_fields()->AddVarint(3, d.coin() ? 99 : (1ull << 32) + 2);  // type out of the enum
  if (d.coin(0.5)) {
    auto& c = *o.mutable_vehicle_classification();
    c.set_type(static_cast<osi3::MovingObject::VehicleClassification::Type>(d.integer(0, 15)));
    if (d.coin(0.2)) c.set_has_trailer(d.coin());
    if (d.coin(0.2)) identifier(d, *c.mutable_trailer_id());
    if (d.coin(0.1)) c.mutable_unknown_fields()->AddVarint(1, static_cast<std::uint64_t>(-3));
  }
  if (d.coin(0.5)) {
    auto& a = *o.mutable_vehicle_attributes();
    if (d.coin(0.8)) vector3d(d, *a.mutable_bbcenter_to_rear());
    if (d.coin(0.2)) vector3d(d, *a.mutable_bbcenter_to_front());
    if (d.coin(0.2)) identifier(d, *a.mutable_driver_id());
    if (d.coin(0.2)) a.set_number_wheels(static_cast<std::uint32_t>(d.id()));
    if (d.coin(0.2)) a.set_radius_wheel(d.real());
  }
  if (d.coin(0.1)) o.set_model_reference("car.glb");
  maybe_unknown(d, o);
}

void stationary_object(RandomView& d, osi3::StationaryObject& o) {
  if (d.coin(0.9)) identifier(d, *o.mutable_id());
  if (d.coin(0.9)) {
    auto& b = *o.mutable_base();
    random_box(d, b);
    if (d.coin(0.1)) b.mutable_unknown_fields()->AddLengthDelimited(4, std::string("\x09\0\0\0\0\0\0\xf0\x3f", 9));
    maybe_unknown(d, b);
  }
  if (d.coin(0.8)) {
    auto& c = *o.mutable_classification();
    if (d.coin(0.9)) c.set_type(static_cast<osi3::StationaryObject::Classification::Type>(d.integer(0, 18)));
    if (d.coin(0.7)) c.set_material(static_cast<osi3::StationaryObject::Classification::Material>(d.integer(0, 8)));
    if (d.coin(0.1)) c.mutable_unknown_fields()->AddVarint(1, d.coin() ? 19 : (1ull << 32) + 3);  // out of the enum
    if (d.coin(0.1)) c.mutable_unknown_fields()->AddVarint(3, 2);  // density, not in the subset
  }
  if (d.coin(0.1)) o.mutable_unknown_fields()->AddLengthDelimited(4, "tree.glb");  // model_reference
  maybe_unknown(d, o);
}

void lane_boundary(RandomView& d, osi3::LaneBoundary& l) {
  if (d.coin(0.9)) identifier(d, *l.mutable_id());
  for (int k = d.integer(0, 5); k > 0; --k) {
    auto& p = *l.add_boundary_line();
    if (d.coin(0.9)) vector3d(d, *p.mutable_position());
    if (d.coin(0.2)) p.set_width(d.real());
  }
  if (d.coin(0.9)) {
    l.mutable_classification()->set_type(static_cast<osi3::LaneBoundary::Classification::Type>(d.integer(0, 13)));
    if (d.coin(0.3)) l.mutable_classification()->set_color(osi3::LaneBoundary::Classification::COLOR_WHITE);
    if (d.coin(0.1)) l.mutable_classification()->mutable_unknown_fields()->AddVarint(1, 14);
  }
  maybe_unknown(d, l);
}

osi3::SensorView random_view(RandomView& d) {
  osi3::SensorView v;
  if (d.coin(0.3)) v.mutable_version()->set_version_major(3);
  if (d.coin(0.9)) timestamp(d, *v.mutable_timestamp());
  if (d.coin(0.8)) identifier(d, *v.mutable_sensor_id());
  if (d.coin(0.8)) mount(d, *v.mutable_mounting_position());
  if (d.coin(0.2)) mount(d, *v.mutable_mounting_position_rmse());
  if (d.coin(0.9)) {
    auto& gt = *v.mutable_global_ground_truth();
    if (d.coin(0.3)) gt.mutable_version()->set_version_minor(8);
    if (d.coin(0.5)) timestamp(d, *gt.mutable_timestamp());
    if (d.coin(0.5)) identifier(d, *gt.mutable_host_vehicle_id());
    for (int i = d.integer(0, 6); i > 0; --i) moving_object(d, *gt.add_moving_object());
    for (int i = d.integer(0, 3); i > 0; --i) stationary_object(d, *gt.add_stationary_object());
    for (int i = d.integer(0, 3); i > 0; --i) lane_boundary(d, *gt.add_lane_boundary());
    maybe_unknown(d, gt);
  }
  if (d.coin(0.7)) identifier(d, *v.mutable_host_vehicle_id());
  for (int i = d.integer(0, 3); i > 0; --i) {
    auto& lv = *v.add_lidar_sensor_view();
    if (!d.coin(0.9)) continue;
    auto& c = *lv.mutable_view_configuration();
    if (d.coin(0.7)) identifier(d, *c.mutable_sensor_id());
    if (d.coin(0.7)) mount(d, *c.mutable_mounting_position());
    if (d.coin(0.2)) mount(d, *c.mutable_mounting_position_rmse());
    maybe_unknown(d, c);
  }
  maybe_unknown(d, v);
  return v;
}

// The messages of a binary trace, up to the first bad length field.
std::vector<std::string> messages_of(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  lidarsim::osi::TraceReader reader(in, path.string());
  std::vector<std::string> out;
  std::string bytes;
  try {
    while (reader.next(bytes)) out.push_back(bytes);
  } catch (const lidarsim::Error&) {
  }
  return out;
}

std::string decode_error(const std::string& bytes) {
  lidarsim::osi::msg::SensorView v;
  try {
    lidarsim::osi::decode_sensor_view(bytes, "x.osi", 7, v);
  } catch (const lidarsim::Error& e) {
    return e.what();
  }
  return "";
}

std::string tag(int field, int type) {
  std::string s;
  for (std::uint64_t v = static_cast<std::uint64_t>(field) << 3 | static_cast<std::uint64_t>(type); ; v >>= 7) {
    s.push_back(static_cast<char>(v < 0x80 ? v : (v & 0x7f) | 0x80));
    if (v < 0x80) return s;
  }
}
std::string length_delimited(int field, const std::string& body) {
  return tag(field, 2) + static_cast<char>(body.size()) + body;  // bodies under 128 bytes here
}

}  // namespace

TEST(OsiSensorViewDecoder, AgreesWithLibprotobufOnTheBundledTraceAndTheFuzzRegressions) {
  const fs::path src = LIDARSIM_SOURCE_DIR;
  std::vector<fs::path> traces = {src / "tests/osi/data/demo_sv_osi_3.5.0.osi"};
  for (const auto& e : fs::directory_iterator(src / "fuzz/regressions/osi_trace")) traces.push_back(e.path());
  int messages = 0;
  for (const fs::path& t : traces)
    for (const std::string& m : messages_of(t)) {
      EXPECT_EQ(compare_with_libprotobuf(m), "") << t << " message " << messages;
      ++messages;
    }
  EXPECT_GE(messages, 10);  // the bundled trace has 2, the regressions up to 3 each
}

TEST(OsiSensorViewDecoder, AgreesWithLibprotobufOnRandomMergedTruncatedAndMutatedMessages) {
  RandomView d(29);
  int accepted = 0, refused = 0;
  for (int n = 0; n < 200; ++n) {
    const std::string a = random_view(d).SerializeAsString();
    ASSERT_EQ(compare_with_libprotobuf(a), "") << "message " << n;
    // Concatenated messages merge (repeated fields append, submessages merge, scalars: the last).
    ASSERT_EQ(compare_with_libprotobuf(a + random_view(d).SerializeAsString()), "") << "merged " << n;
    std::string error;
    if (n < 20) {  // every truncation of the first ones
      for (std::size_t k = 0; k < a.size(); ++k) {
        const std::string cut = a.substr(0, k);
        ASSERT_EQ(compare_with_libprotobuf(cut, &error), "") << "message " << n << " cut at " << k;
      }
    }
    for (int m = 0; m < 20 && !a.empty(); ++m) {  // a few bytes changed
      std::string b = a;
      for (int c = d.integer(1, 3); c > 0; --c)
        b[static_cast<std::size_t>(d.integer(0, static_cast<int>(b.size()) - 1))] =
            static_cast<char>(d.integer(0, 255));
      error.clear();
      ASSERT_EQ(compare_with_libprotobuf(b, &error), "") << "message " << n << " mutation " << m;
      (error.empty() ? accepted : refused)++;
    }
  }
  EXPECT_GT(accepted, 400);  // both outcomes are exercised
  EXPECT_GT(refused, 400);
}

// The rules of osi/wire_reader.h one by one, each against libprotobuf.
TEST(OsiSensorViewDecoder, FollowsLibprotobufOnEveryWireRule) {
  const std::string ts = length_delimited(2, tag(1, 0) + "\x05"s);  // timestamp { seconds: 5 }
  struct Case {
    const char* name;
    std::string bytes;
    bool valid;
  };
  const std::vector<Case> cases = {
      {"non-minimal varint and tag", tag(2, 2) + "\x04"s + "\x88\x00"s + "\x85\x00"s, true},
      {"non-minimal unknown field, echoed", tag(2, 2) + "\x04"s + "\xc8\x00"s + "\x85\x00"s, true},
      {"field number 0", tag(0, 0) + "\x01"s, false},
      {"wire type 6", "\x16\x01"s, false},
      {"wire type 7", "\x17\x01"s, false},
      {"end group outside a group", tag(9, 4), false},
      {"group", tag(9, 3) + tag(1, 0) + "\x01"s + tag(9, 4) + ts, true},
      {"group ended by another field", tag(9, 3) + tag(10, 4), false},
      {"group without its end", tag(9, 3) + tag(1, 0) + "\x01"s, false},
      {"varint of 10 bytes", tag(99, 0) + std::string(9, '\xff') + "\x01"s, true},
      {"varint of 11 bytes", tag(99, 0) + std::string(10, '\xff') + "\x01"s, false},
      {"tag of 5 bytes", "\xc8\x80\x80\x80\x00"s + "\x01"s, true},
      {"tag of 6 bytes", "\xc8\x80\x80\x80\x80\x00"s + "\x01"s, false},
      {"tag beyond 32 bits", "\xc8\x80\x80\x80\x70"s + "\x01"s, true},
      {"length of 5 bytes", tag(2, 2) + "\x80\x80\x80\x80\x00"s, true},
      {"length past the end", tag(2, 2) + "\x05"s + tag(1, 0), false},
      {"known field, other wire type",
       length_delimited(2, tag(1, 1) + "12345678"s) + length_delimited(3, tag(1, 2) + "\x00"s), true},
      {"fixed32", tag(50, 5) + "1234"s, true},
      {"fixed32 truncated", tag(50, 5) + "123"s, false},
      {"empty", "", true},
  };
  for (const auto& [name, bytes, valid] : cases) {
    EXPECT_EQ(compare_with_libprotobuf(bytes), "") << name;
    EXPECT_EQ(decode_error(bytes).empty(), valid) << name << ": " << decode_error(bytes);
  }

  // Nesting: 100 groups below the SensorView parse, 101 do not.
  for (int depth : {99, 100, 101}) {
    std::string g;
    for (int i = 0; i < depth; ++i) g += tag(9, 3);
    for (int i = 0; i < depth; ++i) g += tag(9, 4);
    EXPECT_EQ(compare_with_libprotobuf(g), "") << depth << " groups";
    EXPECT_EQ(decode_error(g).empty(), depth <= 100) << depth << " groups";
  }
}

TEST(OsiSensorViewDecoder, AMalformedMessageIsOneErrorNamingTheField) {
  osi3::SensorView v;
  auto* gt = v.mutable_global_ground_truth();
  for (int i = 0; i < 4; ++i) gt->add_moving_object()->mutable_base()->mutable_position()->set_x(i);
  const std::string bytes = v.SerializeAsString();
  // The last object's position is the last field: cut its last byte.
  EXPECT_EQ(decode_error(bytes.substr(0, bytes.size() - 1)),
            "x.osi: message 7: SensorView.global_ground_truth.moving_object[3].base.position.x: truncated");
  const std::string torn = decode_error(bytes.substr(0, bytes.size() - 9));  // the position's length says 9
  EXPECT_EQ(torn.rfind("x.osi: message 7: SensorView.global_ground_truth.moving_object[3].base.position: truncated", 0),
            0u)
      << torn;
  EXPECT_NE(decode_error(std::string("\x17\x01")).find("SensorView: field 2: wire type 7 does not exist"),
            std::string::npos);
}
