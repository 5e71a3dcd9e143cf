#pragma once
// osi3.SensorView wire bytes -> osi::msg::SensorView (osi/messages.h), without Protocol Buffers:
// what the FMU reads (it links no libprotobuf) and `lidar-infer osi` too. A message decodes here
// exactly when libprotobuf's ParseFromArray accepts it under osi/proto/osi3_subset.proto, into the
// values its accessors give (tests/osi/test_sensor_view_decoder.cpp checks both against
// libprotobuf); the rules are in osi/wire_reader.h.
#include <string>
#include <string_view>

#include "osi/messages.h"

namespace lidarsim::osi {

// Decodes `bytes` into `out` (reset first). A malformed or truncated message throws
// lidarsim::Error "<source>: message <index>: SensorView.<field path>: <what>".
void decode_sensor_view(std::string_view bytes, const std::string& source, long index, msg::SensorView& out);

// One echoed message alone (its bytes as a field of the SensorView carries them); errors name
// `type` ("Timestamp", ...) as the root of the path.
void decode_message(std::string_view bytes, msg::Timestamp& out);
void decode_message(std::string_view bytes, msg::Identifier& out);
void decode_message(std::string_view bytes, msg::MountingPosition& out);

// An echoed message as libprotobuf serializes it after parsing: the fields present in field-number
// order, then the unknown ones.
std::string wire_bytes(const msg::Timestamp& m);
std::string wire_bytes(const msg::Identifier& m);
std::string wire_bytes(const msg::MountingPosition& m);

}  // namespace lidarsim::osi
