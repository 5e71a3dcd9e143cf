#include "pgm/encoder.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include <nlohmann/json.hpp>

#include "common/error.h"

namespace lidarsim::pgm {
namespace {

std::pair<float, float> default_scale(const std::string& name, float range_max) {
  const float pi = std::numbers::pi_v<float>;
  if (name == "incidence") return {0.f, 2.f / pi};
  if (name == "elevation" || name == "azimuth") return {0.f, 1.f / pi};
  if (name == "height") return {0.f, 1.f / 3.f};
  if (name == "x" || name == "y" || name == "z") return {0.f, 1.f / range_max};
  return {0.f, 1.f};
}

std::pair<float, float> scale_of(const EncoderConfig& cfg, const std::string& name) {
  auto it = cfg.scales.find(name);
  return it != cfg.scales.end() ? it->second : default_scale(name, cfg.range_max_m);
}

}  // namespace

int EncoderConfig::input_channels() const { return static_cast<int>(input_names().size()); }

std::vector<std::string> EncoderConfig::input_names() const {
  std::vector<std::string> names;
  for (const auto& c : channels) {
    if (c == "class" && class_one_hot) {
      for (const auto& g : class_groups) names.push_back("class:" + g.name);
    } else if (c == "material" && material_one_hot) {
      for (int m = 0; m < material::count; ++m) names.push_back("material:" + material_name(m));
    } else {
      names.push_back(c);
    }
  }
  return names;
}

std::string EncoderConfig::to_json() const {
  nlohmann::json j;
  j["version"] = 1;
  j["channels"] = channels;
  j["target"] = target;
  j["range_max_m"] = range_max_m;
  j["class_one_hot"] = class_one_hot;
  j["material_one_hot"] = material_one_hot;
  nlohmann::json groups = nlohmann::json::array();
  for (const auto& g : class_groups) {
    std::vector<std::string> members;
    for (int c : g.classes) members.push_back(class_name(c));
    groups.push_back({{"name", g.name}, {"classes", members}});
  }
  j["class_groups"] = groups;
  nlohmann::json scales_json = nlohmann::json::object();
  for (const auto& [name, os] : scales) scales_json[name] = {{"offset", os.first}, {"scale", os.second}};
  j["scales"] = scales_json;
  return j.dump();
}

EncoderConfig EncoderConfig::from_json(const std::string& text, const std::string& where) {
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(text);
  } catch (const nlohmann::json::exception& e) {
    throw input_error(where, "encoder", std::string("not valid JSON: ") + e.what());
  }
  if (!j.is_object()) throw input_error(where, "encoder", "expected a JSON object");
  EncoderConfig cfg;
  try {
    if (j.value("version", 0) != 1) throw input_error(where, "version", "expected 1");
    cfg.channels = j.at("channels").get<std::vector<std::string>>();
    cfg.target = j.at("target").get<std::string>();
    cfg.range_max_m = j.at("range_max_m").get<float>();
    cfg.class_one_hot = j.at("class_one_hot").get<bool>();
    cfg.material_one_hot = j.at("material_one_hot").get<bool>();
    cfg.class_groups.clear();
    for (const auto& g : j.at("class_groups")) {
      ClassGroup group;
      group.name = g.at("name").get<std::string>();
      for (const auto& c : g.at("classes")) group.classes.push_back(class_from_name(c.get<std::string>()));
      cfg.class_groups.push_back(group);
    }
    cfg.scales.clear();
    for (const auto& [name, os] : j.at("scales").items())
      cfg.scales[name] = {os.at("offset").get<float>(), os.at("scale").get<float>()};
  } catch (const nlohmann::json::exception& e) {
    throw input_error(where, "encoder", std::string("malformed: ") + e.what());
  } catch (const Error& e) {
    throw input_error(where, "encoder", e.what());
  }
  if (cfg.channels.empty()) throw input_error(where, "channels", "need at least one input channel");
  if (!(cfg.range_max_m > 0) || !std::isfinite(cfg.range_max_m))
    throw input_error(where, "range_max_m", "must be a positive finite number");
  for (const auto& [name, os] : cfg.scales)
    if (!std::isfinite(os.first) || !std::isfinite(os.second))
      throw input_error(where, "scales." + name, "offset and scale must be finite");
  return cfg;
}

void EncoderConfig::check_channels(const std::vector<std::string>& available, const std::string& where) const {
  auto need = channels;
  need.push_back(target);
  for (const auto& c : need) {
    if (c == "mask") continue;  // the mask always exists (a dataset's /mask)
    if (std::find(available.begin(), available.end(), c) == available.end()) {
      std::string have;
      for (const auto& a : available) have += (have.empty() ? "" : ", ") + a;
      throw input_error(where, "channel '" + c + "'", "required by the encoder but missing (have: " + have + ")");
    }
  }
}

const float* ChannelView::channel(const std::string& name, const std::string& where) const {
  auto it = std::find(names->begin(), names->end(), name);
  if (it == names->end()) throw input_error(where, "channel '" + name + "'", "missing");
  return data + static_cast<std::size_t>(it - names->begin()) * rows * cols;
}

ChannelView view_of(const PolarGridMap& pgm) {
  ChannelView v;
  v.names = &pgm.channel_names();
  v.data = pgm.data().data();
  v.rows = pgm.rows();
  v.cols = pgm.cols();
  return v;
}

void encode_input(const ChannelView& in, const EncoderConfig& cfg, nn::Tensor& out, int n) {
  const auto& s = out.shape();
  const int C = cfg.input_channels();
  if (s.c != C || s.h != in.rows || s.w != in.cols || n < 0 || n >= s.n)
    throw Error("encoder: output tensor " + s.str() + " does not fit image " + std::to_string(n) + " of [N, " +
                std::to_string(C) + ", " + std::to_string(in.rows) + ", " + std::to_string(in.cols) + "]");
  const std::size_t plane = static_cast<std::size_t>(in.rows) * in.cols;
  const float* mask = in.mask ? in.mask : in.channel("mask", "encoder input");
  int oc = 0;
  auto dst = [&](int c) { return out.channel(n, c); };
  for (const auto& name : cfg.channels) {
    if (name == "mask") {
      std::copy(mask, mask + plane, dst(oc++));
      continue;
    }
    const float* src = in.channel(name, "encoder input");
    if (name == "class" && cfg.class_one_hot) {
      std::vector<int> group_of(class_count(), -1);
      for (int g = 0; g < static_cast<int>(cfg.class_groups.size()); ++g)
        for (int c : cfg.class_groups[g].classes) group_of[c] = g;
      const int first = oc;
      oc += static_cast<int>(cfg.class_groups.size());
      for (int c = first; c < oc; ++c) std::fill(dst(c), dst(c) + plane, 0.f);
      for (std::size_t i = 0; i < plane; ++i) {
        if (mask[i] <= 0) continue;
        const int id = static_cast<int>(src[i]);
        if (id >= 0 && id < class_count() && group_of[id] >= 0) dst(first + group_of[id])[i] = 1.f;
      }
    } else if (name == "material" && cfg.material_one_hot) {
      const int first = oc;
      oc += material::count;
      for (int c = first; c < oc; ++c) std::fill(dst(c), dst(c) + plane, 0.f);
      for (std::size_t i = 0; i < plane; ++i) {
        if (mask[i] <= 0) continue;
        const int id = static_cast<int>(src[i]);
        if (id >= 0 && id < material::count) dst(first + id)[i] = 1.f;
      }
    } else {
      float offset = 0, scale = 1;
      if (name == "range") scale = 1.f / cfg.range_max_m;
      else if (name == "class") scale = 1.f / class_count();
      else if (name == "material") scale = 1.f / material_count();
      else std::tie(offset, scale) = scale_of(cfg, name);
      float* d = dst(oc++);
      for (std::size_t i = 0; i < plane; ++i) d[i] = mask[i] > 0 ? (src[i] - offset) * scale : 0.f;
    }
  }
}

nn::Tensor encode_input(const PolarGridMap& pgm, const EncoderConfig& config) {
  nn::Tensor out(1, config.input_channels(), pgm.rows(), pgm.cols());
  encode_input(view_of(pgm), config, out, 0);
  return out;
}

nn::Tensor encode_target(const PolarGridMap& pgm, const EncoderConfig& config) {
  nn::Tensor out(1, 1, pgm.rows(), pgm.cols());
  const float* src = pgm.channel(config.target);
  const float* mask = pgm.channel("mask");
  for (std::size_t i = 0; i < pgm.cells(); ++i) out.data()[i] = mask[i] > 0 ? src[i] : 0.f;
  return out;
}

nn::Tensor encode_mask(const PolarGridMap& pgm) {
  nn::Tensor out(1, 1, pgm.rows(), pgm.cols());
  const float* mask = pgm.channel("mask");
  for (std::size_t i = 0; i < pgm.cells(); ++i) out.data()[i] = mask[i] > 0 ? 1.f : 0.f;
  return out;
}

}  // namespace lidarsim::pgm
