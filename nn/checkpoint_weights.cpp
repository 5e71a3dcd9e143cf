#include "nn/checkpoint_weights.h"

#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>
#include <vector>

#include "common/atomic_file.h"
#include "common/error.h"
#include "nn/heads.h"

namespace lidarsim::nn {
namespace {

static_assert(std::endian::native == std::endian::little, "the value bytes are written as in memory");
// Format 2 is format 1 with header.unet.spread_scale (the spread head's calibration factor,
// UNetConfig::spread_scale): a format-1 reader would sample with the uncalibrated scale, so it
// refuses the file by its magic line. A model whose factor is 1 is still written as format 1.
// Format 3 is format 2 with header.unet.spread_residual (UNetConfig::spread_residual, the
// residual's quantiles and the targets' grid), refused by format-1-2 readers for the same reason.
// Format 4 is format 3 (every field of it) with a zero_logit head (nn/heads.h; as checkpoint
// format 5, nn/checkpoint.cpp): format-1-3 readers would draw without the zeros.
constexpr int kNewestWeightsFormat = 4;
constexpr std::size_t kMaxHeader = std::size_t{64} << 20;

std::uint64_t fnv1a64(const unsigned char* p, std::size_t n) {
  std::uint64_t h = 0xcbf29ce484222325ull;
  for (std::size_t i = 0; i < n; ++i) h = (h ^ p[i]) * 0x100000001b3ull;
  return h;
}

std::string hex16(std::uint64_t v) {
  char text[17];
  std::snprintf(text, sizeof text, "%016llx", static_cast<unsigned long long>(v));
  return text;
}

nlohmann::json shape_json(const Shape& s) { return nlohmann::json::array({s.n, s.c, s.h, s.w}); }

int format_for(const UNetConfig& c) {
  if (head_channel(c.heads, HeadKind::zero_logit) >= 0) return 4;
  return !c.spread_residual.empty() ? 3 : c.spread_scale != 1.f ? 2 : 1;
}

nlohmann::json unet_json(const UNetConfig& c) {
  nlohmann::json u = {{"in_channels", c.in_channels},
          {"outputs", c.out_channels},
          {"base", c.base},
          {"depth", c.depth},
          {"row_affine_rows", c.row_affine_rows},
          {"heads", heads_text(c.heads)},
          {"lookup",
           {{"classes", c.lookup.classes},
            {"class_channel", c.lookup.class_channel},
            {"range_channel", c.lookup.range_channel},
            {"range_bins", c.lookup.range_bins},
            {"rows", c.lookup.rows},
            {"bin_width", c.lookup.bin_width}}}};
  if (format_for(c) >= 2) u["spread_scale"] = c.spread_scale;
  if (format_for(c) >= 3) u["spread_residual"] = nlohmann::json::parse(spread_residual_json(c.spread_residual));
  return u;
}

// Typed access to the header: every lookup names the field ("header.unet.base") in its error.
class Fields {
 public:
  explicit Fields(std::string file) : file_(std::move(file)) {}
  [[noreturn]] void fail(const std::string& field, const std::string& what) const {
    throw input_error(file_, field, what);
  }
  const nlohmann::json& member(const nlohmann::json& obj, const std::string& where, const char* key,
                               nlohmann::json::value_t type) const {
    const auto it = obj.find(key);
    const std::string field = where + "." + key;
    if (it == obj.end()) fail(field, "missing");
    const bool ok = type == nlohmann::json::value_t::number_integer
                        ? it->is_number_integer()
                        : (type == nlohmann::json::value_t::number_float ? it->is_number() : it->type() == type);
    if (!ok) fail(field, std::string("expected ") + nlohmann::json(type).type_name() + ", got " + it->type_name());
    return *it;
  }
  // An integer in [lo, 2^20].
  int integer(const nlohmann::json& obj, const std::string& where, const char* key, int lo) const {
    const std::int64_t v = member(obj, where, key, nlohmann::json::value_t::number_integer).get<std::int64_t>();
    if (v < lo || v > 1 << 20)
      fail(where + "." + key, "expected an integer in [" + std::to_string(lo) + ", 2^20], got " + std::to_string(v));
    return static_cast<int>(v);
  }

 private:
  std::string file_;
};

UNetConfig unet_from(const Fields& f, const nlohmann::json& h, int format) {
  using V = nlohmann::json::value_t;
  const nlohmann::json& u = f.member(h, "header", "unet", V::object);
  UNetConfig c;
  c.in_channels = f.integer(u, "header.unet", "in_channels", 1);
  c.out_channels = f.integer(u, "header.unet", "outputs", 1);
  c.base = f.integer(u, "header.unet", "base", 1);
  c.depth = f.integer(u, "header.unet", "depth", 1);
  c.row_affine_rows = f.integer(u, "header.unet", "row_affine_rows", 0);
  const std::string heads = f.member(u, "header.unet", "heads", V::string).get<std::string>();
  if (!heads.empty()) {
    try {
      c.heads = parse_heads(heads, "value");
      check_heads(c.heads, c.out_channels, "value");
    } catch (const Error& e) {
      f.fail("header.unet.heads", e.what());
    }
  }
  const nlohmann::json& lk = f.member(u, "header.unet", "lookup", V::object);
  c.lookup.classes = f.integer(lk, "header.unet.lookup", "classes", 0);
  if (c.lookup.classes > 0) {
    c.lookup.class_channel = f.integer(lk, "header.unet.lookup", "class_channel", 0);
    c.lookup.range_channel = f.integer(lk, "header.unet.lookup", "range_channel", 0);
    c.lookup.range_bins = f.integer(lk, "header.unet.lookup", "range_bins", 1);
    c.lookup.rows = f.integer(lk, "header.unet.lookup", "rows", 1);
    c.lookup.bin_width = f.member(lk, "header.unet.lookup", "bin_width", V::number_float).get<float>();
    if (!(c.lookup.bin_width > 0) || !std::isfinite(c.lookup.bin_width))
      f.fail("header.unet.lookup.bin_width", "expected a finite number > 0");
  }
  if (format >= 2) {
    const double v = f.member(u, "header.unet", "spread_scale", V::number_float).get<double>();
    if (!(v > 0) || !std::isfinite(v) || v > 1e6) f.fail("header.unet.spread_scale", "expected a finite number > 0");
    if (!has_spread_head(c.heads)) f.fail("header.unet.spread_scale", "present, but header.unet.heads has no spread head");
    c.spread_scale = static_cast<float>(v);
  } else if (u.contains("spread_scale")) {
    f.fail("header.unet.spread_scale", "present in a format-1 file (format 2 carries it)");
  }
  if (format >= 3) {
    if (!has_spread_head(c.heads)) f.fail("header.unet.spread_residual", "format 3, but header.unet.heads has no spread head");
    try {
      c.spread_residual = parse_spread_residual(f.member(u, "header.unet", "spread_residual", V::object).dump(), "value");
    } catch (const Error& e) {
      f.fail("header.unet.spread_residual", e.what());
    }
  } else if (u.contains("spread_residual")) {
    f.fail("header.unet.spread_residual", "present in a format-" + std::to_string(format) + " file (format 3 carries it)");
  }
  const bool zero_head = head_channel(c.heads, HeadKind::zero_logit) >= 0;
  if (zero_head && format < 4)
    f.fail("header.unet.heads", "a zero_logit head in a format-" + std::to_string(format) + " file (format 4 carries it)");
  if (format >= 4 && !zero_head) f.fail("header.unet.heads", "format 4, but no zero_logit head");
  return c;
}

// The parameter list must be the model's, name and shape, in order: the values are read by it.
void check_params(const Fields& f, const nlohmann::json& h, const ParamArena& params) {
  using V = nlohmann::json::value_t;
  const nlohmann::json& list = f.member(h, "header", "params", V::array);
  const std::vector<ParamInfo>& infos = params.infos();
  if (list.size() != infos.size())
    f.fail("header.params", std::to_string(list.size()) + " entries, the model described by header.unet has " +
                                std::to_string(infos.size()) + " parameters");
  for (std::size_t i = 0; i < infos.size(); ++i) {
    const std::string where = "header.params[" + std::to_string(i) + "]";
    if (!list[i].is_object()) f.fail(where, "expected an object");
    const std::string name = f.member(list[i], where, "name", V::string).get<std::string>();
    if (name != infos[i].name) f.fail(where + ".name", "\"" + name + "\", the model expects \"" + infos[i].name + "\"");
    if (f.member(list[i], where, "shape", V::array) != shape_json(infos[i].shape))
      f.fail(where + ".shape", list[i]["shape"].dump() + ", the model expects " + shape_json(infos[i].shape).dump());
  }
}

std::string read_all(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw input_error(path.string(), "file", "cannot be opened");
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) throw input_error(path.string(), "file", "read failed");
  return bytes;
}

}  // namespace

void save_weights(const std::filesystem::path& path, const UNet& model,
                  const std::map<std::string, std::string>& attributes) {
  const ParamArena& params = model.params();
  nlohmann::json list = nlohmann::json::array();
  for (const ParamInfo& info : params.infos()) list.push_back({{"name", info.name}, {"shape", shape_json(info.shape)}});
  const auto* values = reinterpret_cast<const unsigned char*>(params.values());
  const std::size_t value_bytes = params.size() * sizeof(float);
  const nlohmann::json header = {{"unet", unet_json(model.config())},
                                 {"attributes", attributes},
                                 {"params", list},
                                 {"values", params.size()},
                                 {"fnv1a64", hex16(fnv1a64(values, value_bytes))}};
  const std::string text = header.dump();
  std::string bytes = std::string(kWeightsMagic) + std::to_string(format_for(model.config())) + "\n";
  const std::uint64_t length = text.size();
  bytes.append(reinterpret_cast<const char*>(&length), sizeof length);
  bytes += text;
  bytes.append(reinterpret_cast<const char*>(values), value_bytes);
  write_file_atomically(path, bytes);
}

bool is_weights_file(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::string head(std::strlen(kWeightsMagic), '\0');
  return in.read(head.data(), static_cast<std::streamsize>(head.size())) && head == kWeightsMagic;
}

Weights read_weights(const std::filesystem::path& path) {
  const std::string file = path.string();
  const Fields f(file);
  const std::string bytes = read_all(path);
  const std::size_t eol = bytes.find('\n');
  if (eol == std::string::npos || eol > 64 || bytes.compare(0, std::strlen(kWeightsMagic), kWeightsMagic) != 0)
    f.fail("magic", "not a lidarsim weights file (it begins with \"" + std::string(kWeightsMagic) + "<format>\")");
  int format = 0;
  for (int v = 1; v <= kNewestWeightsFormat; ++v)
    if (bytes.substr(0, eol) == std::string(kWeightsMagic) + std::to_string(v)) format = v;
  if (format == 0)
    f.fail("magic", "\"" + bytes.substr(0, eol) + "\": this build reads formats 1 to " + std::to_string(kNewestWeightsFormat));
  std::size_t at = eol + 1;
  std::uint64_t length = 0;
  if (bytes.size() - at < sizeof length) f.fail("header length", "torn: the file ends after " + std::to_string(bytes.size()) + " bytes");
  std::memcpy(&length, bytes.data() + at, sizeof length);
  at += sizeof length;
  if (length > kMaxHeader || length > bytes.size() - at)
    f.fail("header length", std::to_string(length) + " bytes, but " + std::to_string(bytes.size() - at) + " follow");
  const nlohmann::json h = nlohmann::json::parse(bytes.begin() + static_cast<std::ptrdiff_t>(at),
                                                 bytes.begin() + static_cast<std::ptrdiff_t>(at + length), nullptr, false);
  if (h.is_discarded() || !h.is_object()) f.fail("header", "not a JSON object");
  at += length;

  Weights w{{}, UNet(unet_from(f, h, format))};
  w.meta.unet = w.model.config();
  using V = nlohmann::json::value_t;
  for (const auto& [name, value] : f.member(h, "header", "attributes", V::object).items()) {
    if (!value.is_string()) f.fail("header.attributes." + name, "expected a string");
    w.meta.attributes[name] = value.get<std::string>();
  }
  ParamArena& params = w.model.params();
  check_params(f, h, params);
  const nlohmann::json& count = f.member(h, "header", "values", V::number_integer);
  if (count.get<std::int64_t>() < 0 || count.get<std::uint64_t>() != params.size())
    f.fail("header.values", count.dump() + ", the parameters' shapes add up to " + std::to_string(params.size()));
  const std::size_t value_bytes = params.size() * sizeof(float);
  if (bytes.size() - at != value_bytes)
    f.fail("values", std::to_string(bytes.size() - at) + " bytes after the header, expected " +
                         std::to_string(value_bytes) + " (" + std::to_string(params.size()) + " float32)");
  const auto* values = reinterpret_cast<const unsigned char*>(bytes.data() + at);
  const std::string sum = f.member(h, "header", "fnv1a64", V::string).get<std::string>();
  if (sum != hex16(fnv1a64(values, value_bytes)))
    f.fail("values", "checksum " + hex16(fnv1a64(values, value_bytes)) + " does not match header.fnv1a64 " + sum);
  std::memcpy(params.values(), values, value_bytes);
  return w;
}

}  // namespace lidarsim::nn
