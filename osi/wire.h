#pragma once
// The Protocol Buffers wire format, written by hand for messages too big to build as protobuf
// objects (osi/sensor_data_encoder.h). A message is written in two passes over the same code: a
// Counter measures it, then a Writer writes it into a buffer of exactly that size. Each message
// body is a generic callable `body(sink)` that emits its fields in field-number order, the order
// libprotobuf serializes them in; a submessage is emitted with `sink.message(field, body)`, which
// the Writer measures first to write the length. Only what libprotobuf writes for set proto2
// fields: minimal varints, int32 and enum values sign-extended to 64 bits, doubles as fixed64,
// no packed fields (proto2 repeated scalars are unpacked unless [packed = true]; the subset has none).
#include <bit>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <string_view>

namespace lidarsim::osi::wire {

static_assert(std::endian::native == std::endian::little, "doubles are copied as the wire's little-endian fixed64");

enum WireType : std::uint32_t { kVarint = 0, kFixed64 = 1, kLengthDelimited = 2 };

constexpr std::size_t varint_size(std::uint64_t v) { return (static_cast<std::size_t>(std::bit_width(v | 1)) + 6) / 7; }
constexpr std::size_t tag_size(int field) { return varint_size(static_cast<std::uint64_t>(field) << 3); }
// A length-delimited field whose content has `content` bytes.
constexpr std::size_t length_delimited_size(int field, std::size_t content) {
  return tag_size(field) + varint_size(content) + content;
}

class Counter {
 public:
  void uint(int field, std::uint64_t v) { n_ += tag_size(field) + varint_size(v); }
  // int32, int64 and enum fields: negative values take ten bytes (two's complement, 64 bits).
  void sint(int field, std::int64_t v) { uint(field, static_cast<std::uint64_t>(v)); }
  void f64(int field, double) { n_ += tag_size(field) + 8; }
  // A submessage already serialized (e.g. one echoed from the input).
  void bytes(int field, std::string_view b) { n_ += length_delimited_size(field, b.size()); }
  template <class Body>
  void message(int field, Body&& body);
  // `n` bytes written by `write(char*)` (returns the end), for a hot loop with a size known in advance.
  template <class Write>
  void raw(std::size_t n, Write&&) { n_ += n; }
  std::size_t size() const { return n_; }

 private:
  std::size_t n_ = 0;
};

template <class Body>
std::size_t measure(Body&& body) {
  Counter c;
  body(c);
  return c.size();
}

template <class Body>
void Counter::message(int field, Body&& body) {
  n_ += length_delimited_size(field, measure(body));
}

inline char* put_varint(char* p, std::uint64_t v) {
  while (v >= 0x80) {
    *p++ = static_cast<char>(v | 0x80);
    v >>= 7;
  }
  *p++ = static_cast<char>(v);
  return p;
}
inline char* put_tag(char* p, int field, WireType type) {
  return put_varint(p, static_cast<std::uint64_t>(field) << 3 | type);
}
inline char* put_f64(char* p, int field, double v) {
  p = put_tag(p, field, kFixed64);
  std::memcpy(p, &v, 8);
  return p + 8;
}

// Writes into a buffer the Counter sized; the caller checks that `end()` lands on its end.
class Writer {
 public:
  explicit Writer(char* p) : p_(p) {}
  void uint(int field, std::uint64_t v) { p_ = put_varint(put_tag(p_, field, kVarint), v); }
  void sint(int field, std::int64_t v) { uint(field, static_cast<std::uint64_t>(v)); }
  void f64(int field, double v) { p_ = put_f64(p_, field, v); }
  void bytes(int field, std::string_view b) {
    p_ = put_varint(put_tag(p_, field, kLengthDelimited), b.size());
    if (!b.empty()) std::memcpy(p_, b.data(), b.size());
    p_ += b.size();
  }
  template <class Body>
  void message(int field, Body&& body) {
    p_ = put_varint(put_tag(p_, field, kLengthDelimited), measure(body));
    body(*this);
  }
  template <class Write>
  void raw(std::size_t, Write&& write) { p_ = write(p_); }
  char* end() const { return p_; }

 private:
  char* p_;
};

}  // namespace lidarsim::osi::wire
