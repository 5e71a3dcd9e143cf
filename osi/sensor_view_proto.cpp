// The osi3 message overloads of osi/sensor_view.h. Kept apart from sensor_view.cpp so that code
// which only decodes wire bytes (the FMU) links no libprotobuf: a static library's object is
// linked only when something refers to it.
#include <cmath>

#include "osi/osi3_subset.pb.h"
#include "osi/sensor_view.h"
#include "osi/sensor_view_decoder.h"

namespace lidarsim::osi {

msg::SensorView decoded(const osi3::SensorView& view) {
  msg::SensorView out;
  decode_sensor_view(view.SerializePartialAsString(), "osi3.SensorView", 0, out);
  return out;
}

void scene_from_sensor_view(const osi3::SensorView& view, long index, const std::string& source, IdMap& ids,
                            SceneFrame& out) {
  scene_from_sensor_view(decoded(view), index, source, ids, out);
}

void set_timestamp(double s, osi3::Timestamp& t) {
  auto whole = static_cast<std::int64_t>(std::floor(s));
  auto nanos = static_cast<std::int64_t>(std::llround((s - static_cast<double>(whole)) * 1e9));
  if (nanos >= 1000000000) {
    ++whole;
    nanos -= 1000000000;
  }
  t.set_seconds(whole);
  t.set_nanos(static_cast<std::uint32_t>(nanos));
}

}  // namespace lidarsim::osi
