#include "osi/trace.h"

#include <algorithm>
#include <istream>
#include <ostream>

#include <google/protobuf/message.h>
#include <google/protobuf/text_format.h>

#include "common/error.h"

namespace lidarsim::osi {

TraceReader::TraceReader(std::istream& in, std::string source) : in_(in), source_(std::move(source)) {}

bool TraceReader::next(std::string& bytes) {
  const long index = index_ + 1;
  auto fail = [&](const std::string& what) {
    return Error(source_ + ": message " + std::to_string(index) + ": " + what);
  };
  unsigned char header[4];
  in_.read(reinterpret_cast<char*>(header), 4);
  const std::streamsize got = in_.gcount();
  if (got == 0 && in_.eof()) return false;
  if (got < 4)
    throw fail("length field torn (" + std::to_string(got) + " of 4 bytes before the end of the trace)");
  const std::uint32_t length = static_cast<std::uint32_t>(header[0]) | static_cast<std::uint32_t>(header[1]) << 8 |
                               static_cast<std::uint32_t>(header[2]) << 16 | static_cast<std::uint32_t>(header[3]) << 24;
  if (length > kMaxMessageBytes)
    throw fail("length field says " + std::to_string(length) + " bytes, more than the " +
               std::to_string(kMaxMessageBytes >> 20) + " MiB limit (not a binary OSI trace?)");
  // The body is read in chunks as it arrives, 64 KiB first, then as much as has arrived (at most
  // 1 MiB): a corrupt length field on a short trace costs about what the trace holds, not the
  // 1 GiB it may claim (seen while writing the osi_trace fuzz target), nor 1 MiB per message.
  std::size_t chunk = 64u << 10;
  std::size_t body = 0;
  bytes.clear();
  while (body < length) {
    const std::size_t want = std::min<std::size_t>(chunk, length - body);
    bytes.resize(body + want);
    in_.read(bytes.data() + body, static_cast<std::streamsize>(want));
    body += static_cast<std::size_t>(in_.gcount());
    if (static_cast<std::size_t>(in_.gcount()) < want) break;
    chunk = std::min<std::size_t>(body, 1u << 20);
  }
  if (body < length)
    throw fail("torn: the length field says " + std::to_string(length) + " bytes, the trace ends after " +
               std::to_string(body));
  index_ = index;
  return true;
}

bool TraceReader::next(google::protobuf::Message& message) {
  if (!next(scratch_)) return false;
  message.Clear();
  if (!message.ParseFromString(scratch_))
    throw Error(source_ + ": message " + std::to_string(index_) + ": does not parse as " +
                message.GetDescriptor()->full_name() + " (" + std::to_string(scratch_.size()) + " bytes)");
  return true;
}

TraceFormat trace_format_from_string(const std::string& name) {
  if (name == "binary") return TraceFormat::Binary;
  if (name == "txth") return TraceFormat::Text;
  throw Error("--format: must be binary or txth, got '" + name + "'");
}

TraceWriter::TraceWriter(std::ostream& out, TraceFormat format) : out_(out), format_(format) {}

void TraceWriter::write_framed(std::string& framed) {
  if (format_ != TraceFormat::Binary) throw Error("osi trace: message " + std::to_string(written_) + ": bytes for a text trace");
  if (framed.size() < kLengthBytes) throw Error("osi trace: message " + std::to_string(written_) + ": no length field");
  if (framed.size() - kLengthBytes > kMaxMessageBytes)
    throw Error("osi trace: message " + std::to_string(written_) + ": " + std::to_string(framed.size() - kLengthBytes) +
                " bytes, more than a trace can hold");
  const auto n = static_cast<std::uint32_t>(framed.size() - kLengthBytes);
  for (std::size_t b = 0; b < kLengthBytes; ++b) framed[b] = static_cast<char>(n >> (8 * b) & 0xff);
  out_.write(framed.data(), static_cast<std::streamsize>(framed.size()));
  out_.flush();
  if (!out_) throw Error("osi trace: message " + std::to_string(written_) + ": write failed");
  ++written_;
}

void TraceWriter::write(const google::protobuf::Message& message) {
  if (format_ == TraceFormat::Binary) {
    scratch_.resize(kLengthBytes);
    if (!message.AppendToString(&scratch_))
      throw Error("osi trace: message " + std::to_string(written_) + ": could not be serialized");
    write_framed(scratch_);
    return;
  }
  google::protobuf::TextFormat::PrintToString(message, &scratch_);
  out_ << scratch_ << '\n';
  out_.flush();
  if (!out_) throw Error("osi trace: message " + std::to_string(written_) + ": write failed");
  ++written_;
}

}  // namespace lidarsim::osi
