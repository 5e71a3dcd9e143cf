#pragma once
// Single-channel binary OSI traces: each message is preceded by its length as a 4-byte
// little-endian unsigned integer (the layout of OSI's .osi trace files). The reader works on any
// std::istream, so a file and stdin are read alike, one message at a time; the writer flushes
// after every message so a co-simulation reading our stdout sees each frame as soon as it exists.
#include <cstdint>
#include <iosfwd>
#include <string>

namespace google::protobuf {
class Message;
}

namespace lidarsim::osi {

// A message larger than this is taken for a corrupt length field, not allocated.
inline constexpr std::uint32_t kMaxMessageBytes = 1u << 30;
// The length field in front of each message.
inline constexpr std::size_t kLengthBytes = 4;

class TraceReader {
 public:
  // `source` names the trace in error messages (a path, or "stdin").
  TraceReader(std::istream& in, std::string source);

  // The next message's bytes; false at a clean end (end of input exactly between messages).
  // A torn length field, a length beyond kMaxMessageBytes or a torn body throws lidarsim::Error
  // "<source>: message <index>: <what>".
  bool next(std::string& bytes);
  // Reads and parses the next message into `message` (cleared first); a message that does not
  // parse as that type throws "<source>: message <index>: does not parse as osi3.<Type>".
  bool next(google::protobuf::Message& message);

  long index() const { return index_; }  // 0-based index of the message last returned
  const std::string& source() const { return source_; }

 private:
  std::istream& in_;
  std::string source_;
  long index_ = -1;
  std::string scratch_;
};

enum class TraceFormat { Binary, Text };
// "binary" or "txth"; throws lidarsim::Error for anything else.
TraceFormat trace_format_from_string(const std::string& name);

class TraceWriter {
 public:
  TraceWriter(std::ostream& out, TraceFormat format);
  // Binary: length + serialized bytes. Text (.txth, for people): the protobuf text format of the
  // message followed by one empty line. Flushes the stream; throws lidarsim::Error on a failed write.
  void write(const google::protobuf::Message& message);
  // Binary only: `framed` is kLengthBytes of room followed by a serialized message (as
  // osi::encode_sensor_data writes it with prefix kLengthBytes); the length goes into the room and
  // the whole is written with one call, without a copy. Flushes; throws as write does.
  void write_framed(std::string& framed);
  long written() const { return written_; }

 private:
  std::ostream& out_;
  TraceFormat format_;
  long written_ = 0;
  std::string scratch_;
};

}  // namespace lidarsim::osi
