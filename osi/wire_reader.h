#pragma once
// Reading the Protocol Buffers wire format by hand (the counterpart of osi/wire.h), with
// libprotobuf's rules (v3.21, what ParseFromArray accepts), so that a message decodes here exactly
// when libprotobuf parses it (tests/osi/test_sensor_view_decoder.cpp checks that against it):
//
// - a tag is a varint of at most 5 bytes (kept modulo 2^32), a value varint at most 10 (modulo
//   2^64), a length at most 5 bytes and within the enclosing message;
// - field number 0, wire types 6 and 7, an end-group tag outside its group: malformed;
// - a known field with another wire type than its own is an unknown field (skipped);
// - unknown fields are skipped whole (a group up to its matching end tag), length-delimited ones
//   without looking inside; known submessages are read, so their bytes are checked too;
// - at most 100 levels of submessages and groups below the top-level message.
//
// Every read is bounds-checked; a malformed or truncated field throws lidarsim::Error naming its
// path, e.g. "SensorView.global_ground_truth.moving_object[3].base.position: truncated". The path
// is a chain of stack frames, turned into text only when an error is thrown.
#include <algorithm>
#include <cstdint>
#include <cstring>
#include <string>

#include "common/error.h"
#include "osi/wire.h"

namespace lidarsim::osi::wire {

inline constexpr std::uint32_t kStartGroup = 3, kEndGroup = 4, kFixed32 = 5;
inline constexpr int kMaxDepth = 100;  // libprotobuf's default recursion limit

// Where a reader is: its message's field name (the type name at the root) and its index when the
// field is repeated.
struct Path {
  const Path* parent = nullptr;
  const char* name = "";
  long index = -1;
  std::string str() const {
    std::string s = parent ? parent->str() + "." + name : std::string(name);
    if (index >= 0) s += "[" + std::to_string(index) + "]";
    return s;
  }
};

struct Tag {
  int field = 0;
  std::uint32_t type = 0;
  // The switch key of (field, wire type): known fields are matched on both, so a known field
  // number with another wire type falls through to the unknown fields as libprotobuf has it.
  std::uint64_t key() const { return static_cast<std::uint64_t>(field) << 3 | type; }
};
constexpr std::uint64_t key(int field, std::uint32_t type) { return static_cast<std::uint64_t>(field) << 3 | type; }

class Reader {
 public:
  Reader(const char* begin, const char* end, const Path& path, int depth = kMaxDepth)
      : p_(begin), end_(end), path_(path), depth_(depth) {}

  bool more() const { return p_ < end_; }

  // The next field's tag. End-group tags are only read by skip_group.
  Tag tag() {
    const std::uint32_t v = raw_tag(-1);
    const Tag t{static_cast<int>(v >> 3), v & 7};
    if (t.field == 0) fail_at(nullptr, -1, -1, "field number 0");
    if (t.type == kEndGroup) fail_at(nullptr, -1, t.field, "end-group tag outside its group");
    if (t.type > kFixed32) fail_at(nullptr, -1, t.field, "wire type " + std::to_string(t.type) + " does not exist");
    return t;
  }

  std::uint64_t varint(const char* name) {
    std::uint64_t v = 0;
    for (int i = 0;; ++i) {
      if (p_ == end_) fail_at(name, -1, -1, "truncated");
      const auto b = static_cast<std::uint8_t>(*p_++);
      if (i < 10) v |= static_cast<std::uint64_t>(b & 0x7f) << (7 * i);
      if (b < 0x80) return v;
      if (i == 9) fail_at(name, -1, -1, "varint longer than 10 bytes");
    }
  }

  double f64(const char* name) {
    if (end_ - p_ < 8) fail_at(name, -1, -1, "truncated");
    double v;
    std::memcpy(&v, p_, 8);
    p_ += 8;
    return v;
  }

  // A submessage: `read(Reader&)` reads its fields. Repeated fields pass their element's index.
  // A submessage longer than what is left is read as far as it goes first, so that the error
  // names the innermost field the truncation cut.
  template <class Read>
  void message(const char* name, Read&& read, long index = -1) {
    const std::uint64_t n = length(name, index);
    const Path path{&path_, name, index};
    if (depth_ <= 0) fail_at(name, index, -1, "nested deeper than " + std::to_string(kMaxDepth) + " messages");
    const auto left = static_cast<std::uint64_t>(end_ - p_);
    Reader sub(p_, p_ + std::min(n, left), path, depth_ - 1);
    if (n > left) {
      read(sub);
      fail_at(name, index, -1, truncated(n));
    }
    p_ += n;
    read(sub);
  }

  // A field we do not read (unknown, or known with another wire type, or unused). With `keep`,
  // it is appended there as libprotobuf re-serializes an unknown field.
  void skip(const Tag& t, std::string* keep = nullptr) {
    switch (t.type) {
      case kVarint: {
        const std::uint64_t v = varint(nullptr);
        if (keep) append(*keep, [&](char* p) { return put_varint(put_tag(p, t.field, kVarint), v); });
        return;
      }
      case kFixed64: return skip_fixed(t, 8, keep);
      case kFixed32: return skip_fixed(t, 4, keep);
      case kLengthDelimited: {
        const std::uint64_t n = length(nullptr, -1, t.field);
        if (n > static_cast<std::uint64_t>(end_ - p_)) fail_at(nullptr, -1, t.field, truncated(n));
        if (keep) {
          append(*keep, [&](char* p) { return put_varint(put_tag(p, t.field, kLengthDelimited), n); });
          keep->append(p_, n);
        }
        p_ += n;
        return;
      }
      default: return skip_group(t, keep);  // kStartGroup: tag() lets no other type through
    }
  }

  [[noreturn]] void fail(const char* name, const std::string& what) const { fail_at(name, -1, -1, what); }

 private:
  const char* p_;
  const char* end_;
  const Path& path_;
  int depth_;

  // A tag's varint: at most 5 bytes, bits past 32 dropped (libprotobuf's ReadTag).
  std::uint32_t raw_tag(int group) {
    std::uint32_t v = 0;
    for (int i = 0;; ++i) {
      if (p_ == end_) fail_at(nullptr, -1, group, "tag truncated");
      const auto b = static_cast<std::uint8_t>(*p_++);
      v |= static_cast<std::uint32_t>(b & 0x7f) << (7 * i);
      if (b < 0x80) return v;
      if (i == 4) fail_at(nullptr, -1, group, "tag longer than 5 bytes");
    }
  }

  // A length: at most 5 bytes (libprotobuf's ReadSize); the caller checks it against what is left.
  std::uint64_t length(const char* name, long index, int field = -1) {
    std::uint64_t v = 0;
    for (int i = 0;; ++i) {
      if (p_ == end_) fail_at(name, index, field, "truncated");
      const auto b = static_cast<std::uint8_t>(*p_++);
      v |= static_cast<std::uint64_t>(b & 0x7f) << (7 * i);
      if (b < 0x80) break;
      if (i == 4) fail_at(name, index, field, "length longer than 5 bytes");
    }
    return v;
  }

  std::string truncated(std::uint64_t n) const {
    return "truncated (" + std::to_string(n) + " bytes long, " + std::to_string(end_ - p_) + " left)";
  }

  void skip_fixed(const Tag& t, std::size_t n, std::string* keep) {
    if (static_cast<std::size_t>(end_ - p_) < n) fail_at(nullptr, -1, t.field, "truncated");
    if (keep) {
      append(*keep, [&](char* p) { return put_tag(p, t.field, n == 8 ? kFixed64 : static_cast<WireType>(kFixed32)); });
      keep->append(p_, n);
    }
    p_ += n;
  }

  // A group: fields up to the end-group tag of the same field number, one level deeper.
  void skip_group(const Tag& start, std::string* keep) {
    if (depth_ <= 0) fail_at(nullptr, -1, start.field, "nested deeper than " + std::to_string(kMaxDepth) + " messages");
    if (keep) append(*keep, [&](char* p) { return put_tag(p, start.field, static_cast<WireType>(kStartGroup)); });
    --depth_;
    for (;;) {
      if (p_ == end_) fail_at(nullptr, -1, start.field, "group without its end tag");
      const char* at = p_;
      const std::uint32_t v = raw_tag(start.field);  // as tag(), but an end-group tag ends the group
      if ((v & 7) == kEndGroup) {
        if (static_cast<int>(v >> 3) != start.field)
          fail_at(nullptr, -1, start.field, "group ends with another field's tag");
        break;
      }
      p_ = at;
      skip(tag(), keep);
    }
    ++depth_;
    if (keep) append(*keep, [&](char* p) { return put_tag(p, start.field, static_cast<WireType>(kEndGroup)); });
  }

  template <class Put>
  static void append(std::string& s, Put&& put) {
    char buf[24];
    s.append(buf, static_cast<std::size_t>(put(buf) - buf));
  }

  // "<path>[.name[index]][: field N]: what"; `field` names an unknown field by number.
  [[noreturn]] void fail_at(const char* name, long index, int field, const std::string& what) const {
    std::string where = path_.str();
    if (name) where += std::string(".") + name;
    if (name && index >= 0) where += "[" + std::to_string(index) + "]";
    if (field >= 0) where += ": field " + std::to_string(field);
    throw Error(where + ": " + what);
  }
};

}  // namespace lidarsim::osi::wire
