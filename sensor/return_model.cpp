#include "sensor/return_model.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

#include "common/atomic_file.h"
#include "common/counter_hash.h"
#include "common/error.h"
#include "pgm/materials.h"

namespace lidarsim::sensor {

using nlohmann::json;

ReturnCounts::ReturnCounts(int rows_, int classes_, double bin_m, int bins)
    : rows(rows_), range_bins(bins), classes(classes_), range_bin_m(bin_m) {
  if (rows < 1 || classes < 1 || bins < 1 || !(bin_m > 0))
    throw Error("return counts: rows, classes and range bins must be >= 1 and the bin width > 0");
  cells.assign(static_cast<std::size_t>(rows) * range_bins * classes, 0.0);
  returns.assign(cells.size(), 0.0);
}

int ReturnCounts::range_bin(double range_m) const {
  const int b = static_cast<int>(std::max(0.0, range_m) / range_bin_m);
  return std::min(b, range_bins - 1);
}

void ReturnCounts::add(int row, double range_m, int class_id, bool returned) {
  if (class_id < 0 || class_id >= classes) class_id = 0;
  const std::size_t i = index(row, range_bin(range_m), class_id);
  cells[i] += 1;
  if (returned) returns[i] += 1;
}

void ReturnCounts::add(const pgm::ReturnTarget& t) {
  if (t.rows != rows) throw Error("return counts: a target of " + std::to_string(t.rows) + " rows, the counts have " + std::to_string(rows));
  for (std::size_t i = 0; i < t.label.size(); ++i)
    if (t.label[i] != pgm::ReturnLabel::Sky)
      add(static_cast<int>(i / t.cols), t.range[i], t.class_id[i], t.label[i] == pgm::ReturnLabel::Return);
}

void ReturnCounts::merge(const ReturnCounts& o) {
  if (o.rows != rows || o.range_bins != range_bins || o.classes != classes || o.range_bin_m != range_bin_m)
    throw Error("return counts: cannot merge counts of another shape");
  for (std::size_t i = 0; i < cells.size(); ++i) {
    cells[i] += o.cells[i];
    returns[i] += o.returns[i];
  }
}

ReturnModel ReturnModel::fit(const ReturnCounts& c, const pgm::BeamLayout& layout, double prior) {
  if (layout.rows() != c.rows)
    throw Error("return model: the layout has " + std::to_string(layout.rows()) + " rows, the counts " + std::to_string(c.rows));
  if (!(prior > 0) || !std::isfinite(prior)) throw Error("return model: prior_strength must be > 0");
  ReturnModel m;
  m.layout_ = layout;
  m.counts_ = c;
  m.prior_ = prior;
  const int R = c.rows, B = c.range_bins, K = c.classes;
  // Sums at every level of both chains.
  std::vector<double> nl(R, 0), rl(R, 0), nlb(static_cast<std::size_t>(R) * B, 0), rlb(nlb.size(), 0);
  std::vector<double> nb(B, 0), rb(B, 0), nbk(static_cast<std::size_t>(B) * K, 0), rbk(nbk.size(), 0);
  double n = 0, r = 0;
  for (int l = 0; l < R; ++l)
    for (int b = 0; b < B; ++b)
      for (int k = 0; k < K; ++k) {
        const std::size_t i = c.index(l, b, k);
        const double ni = c.cells[i], ri = c.returns[i];
        n += ni, r += ri;
        nl[l] += ni, rl[l] += ri;
        nlb[static_cast<std::size_t>(l) * B + b] += ni, rlb[static_cast<std::size_t>(l) * B + b] += ri;
        nb[b] += ni, rb[b] += ri;
        nbk[static_cast<std::size_t>(b) * K + k] += ni, rbk[static_cast<std::size_t>(b) * K + k] += ri;
      }
  auto shrink = [prior](double ret, double cells, double parent) { return static_cast<float>((ret + prior * parent) / (cells + prior)); };
  m.global_ = n > 0 ? r / n : 1.0;
  m.laser_.resize(R);
  m.laser_range_.resize(nlb.size());
  m.laser_range_class_.resize(c.cells.size());
  m.range_.resize(B);
  m.range_class_.resize(nbk.size());
  for (int b = 0; b < B; ++b) {
    m.range_[b] = shrink(rb[b], nb[b], m.global_);
    for (int k = 0; k < K; ++k) {
      const std::size_t j = static_cast<std::size_t>(b) * K + k;
      m.range_class_[j] = shrink(rbk[j], nbk[j], m.range_[b]);
    }
  }
  for (int l = 0; l < R; ++l) {
    m.laser_[l] = shrink(rl[l], nl[l], m.global_);
    for (int b = 0; b < B; ++b) {
      const std::size_t j = static_cast<std::size_t>(l) * B + b;
      m.laser_range_[j] = shrink(rlb[j], nlb[j], m.laser_[l]);
      for (int k = 0; k < K; ++k) {
        const std::size_t i = c.index(l, b, k);
        m.laser_range_class_[i] = shrink(c.returns[i], c.cells[i], m.laser_range_[j]);
      }
    }
  }
  return m;
}

float ReturnModel::probability(int row, double range_m, int class_id, bool use_laser) const {
  const int b = counts_.range_bin(range_m);
  const int K = counts_.classes;
  const bool has_class = class_id > 0 && class_id < K;
  if (!use_laser) return has_class ? range_class_[static_cast<std::size_t>(b) * K + class_id] : range_[b];
  if (row < 0 || row >= counts_.rows)
    throw Error("return model: row " + std::to_string(row) + " outside the model's " + std::to_string(counts_.rows) + " rows");
  return has_class ? laser_range_class_[counts_.index(row, b, class_id)]
                   : laser_range_[static_cast<std::size_t>(row) * counts_.range_bins + b];
}

const char* to_string(ReturnKey key) {
  switch (key) {
    case ReturnKey::Laser: return "laser";
    case ReturnKey::Range5m: return "range_5m";
    case ReturnKey::Class: return "class";
    case ReturnKey::Material: return "material";
    case ReturnKey::Azimuth10: return "azimuth_10deg";
    case ReturnKey::Azimuth5: return "azimuth_5deg";
    case ReturnKey::Height: return "height_0.5m";
    case ReturnKey::ClassRange5m: return "class_x_range_5m";
  }
  return "?";
}

ReturnKey return_key_from_string(const std::string& name, const std::string& where) {
  for (int k = 0; k <= static_cast<int>(ReturnKey::ClassRange5m); ++k)
    if (name == to_string(static_cast<ReturnKey>(k))) return static_cast<ReturnKey>(k);
  throw input_error(where, "multipliers/key", "unknown key \"" + name +
                    "\" (expected laser, range_5m, class, material, azimuth_10deg, azimuth_5deg, height_0.5m, class_x_range_5m)");
}

int return_key_size(ReturnKey key, int rows) {
  switch (key) {
    case ReturnKey::Laser: return rows;
    case ReturnKey::Range5m: return 24;
    case ReturnKey::Class: return pgm::class_count();
    case ReturnKey::Material: return pgm::material_count();
    case ReturnKey::Azimuth10: return 36;
    case ReturnKey::Azimuth5: return 72;
    case ReturnKey::Height: return 20;
    case ReturnKey::ClassRange5m: return pgm::class_count() * 24;
  }
  return 0;
}

int return_key(ReturnKey key, int row, double range_m, int class_id, double azimuth_deg, double height_m) {
  const int rb = std::clamp(static_cast<int>(range_m / 5.0), 0, 23);
  const int cls = std::clamp(class_id, 0, pgm::class_count() - 1);
  switch (key) {
    case ReturnKey::Laser: return row;
    case ReturnKey::Range5m: return rb;
    case ReturnKey::Class: return cls;
    case ReturnKey::Material: return pgm::default_material(cls);
    case ReturnKey::Azimuth10: return std::clamp(static_cast<int>(azimuth_deg / 10), 0, 35);
    case ReturnKey::Azimuth5: return std::clamp(static_cast<int>(azimuth_deg / 5), 0, 71);
    case ReturnKey::Height: return std::clamp(static_cast<int>((height_m + 3.0) / 0.5), 0, 19);
    case ReturnKey::ClassRange5m: return cls * 24 + rb;
  }
  return 0;
}

float ReturnModel::probability_at(int row, int col, double range_m, int class_id) const {
  double p = probability(row, range_m, class_id);
  if (multipliers.empty()) return static_cast<float>(p);
  const double az = 360.0 * (col + 0.5) / layout_.columns;
  const double h = range_m * std::sin(layout_.elevations_rad[row]);
  for (const auto& m : multipliers) p *= m.factor[return_key(m.key, row, range_m, class_id, az, h)];
  return static_cast<float>(std::clamp(p, 0.0, 1.0));
}

json ReturnModel::to_json() const {
  json j;
  j["format"] = "lidarsim-returns";
  j["version"] = 1;
  j["source"] = source;
  j["fit_command"] = fit_command;
  j["fit_places"] = fit_places;
  j["layout"] = json::parse(layout_.to_json());
  j["range_bin_m"] = counts_.range_bin_m;
  j["range_bins"] = counts_.range_bins;
  j["prior_strength"] = prior_;
  std::vector<std::string> names;
  for (int k = 0; k < counts_.classes; ++k) names.push_back(pgm::class_name(k));
  j["classes"] = names;
  j["global_return_rate"] = global_;
  j["laser_return_rate"] = laser_;  // shrunk, for readers; recomputed from the counts on load
  // Counts as [row, range bin, class, cells, returns], non-empty entries only: the tables are
  // refitted from them on load, so the file cannot disagree with itself.
  json entries = json::array();
  for (int l = 0; l < counts_.rows; ++l)
    for (int b = 0; b < counts_.range_bins; ++b)
      for (int k = 0; k < counts_.classes; ++k) {
        const std::size_t i = counts_.index(l, b, k);
        if (counts_.cells[i] > 0) entries.push_back({l, b, k, counts_.cells[i], counts_.returns[i]});
      }
  j["counts"] = std::move(entries);
  if (!multipliers.empty()) {
    json ms = json::array();
    for (const auto& m : multipliers) ms.push_back({{"key", to_string(m.key)}, {"factor", m.factor}, {"note", m.note}});
    j["multipliers"] = ms;
  }
  return j;
}

namespace {

const json& member(const json& j, const char* key, const std::string& where) {
  if (!j.is_object() || !j.contains(key)) throw input_error(where, key, "missing");
  return j.at(key);
}

double number(const json& j, const char* key, const std::string& where) {
  const json& v = member(j, key, where);
  if (!v.is_number() || !std::isfinite(v.get<double>())) throw input_error(where, key, "must be a finite number");
  return v.get<double>();
}

}  // namespace

ReturnModel ReturnModel::from_json(const json& j, const std::string& where) {
  if (member(j, "format", where) != "lidarsim-returns")
    throw input_error(where, "format", "must be \"lidarsim-returns\", got " + j.at("format").dump());
  if (number(j, "version", where) != 1) throw input_error(where, "version", "this build reads version 1");
  const pgm::BeamLayout layout = pgm::BeamLayout::from_json(member(j, "layout", where).dump(), where + ": layout");
  const double bin_m = number(j, "range_bin_m", where);
  const double bins = number(j, "range_bins", where);
  if (!(bin_m > 0) || bins < 1 || bins > 1000 || bins != std::floor(bins))
    throw input_error(where, "range_bin_m/range_bins", "must be > 0 and a whole number in 1..1000");
  const auto& names = member(j, "classes", where);
  if (!names.is_array() || static_cast<int>(names.size()) != pgm::class_count())
    throw input_error(where, "classes", "expected the " + std::to_string(pgm::class_count()) + " class names of this build");
  for (int k = 0; k < pgm::class_count(); ++k)
    if (names[k] != pgm::class_name(k))
      throw input_error(where, "classes[" + std::to_string(k) + "]", "expected \"" + pgm::class_name(k) + "\", got " + names[k].dump());
  ReturnCounts c(layout.rows(), pgm::class_count(), bin_m, static_cast<int>(bins));
  const auto& entries = member(j, "counts", where);
  if (!entries.is_array()) throw input_error(where, "counts", "must be an array of [row, bin, class, cells, returns]");
  for (std::size_t e = 0; e < entries.size(); ++e) {
    const auto& x = entries[e];
    const std::string f = "counts[" + std::to_string(e) + "]";
    if (!x.is_array() || x.size() != 5) throw input_error(where, f, "must be [row, bin, class, cells, returns]");
    for (const auto& v : x)
      if (!v.is_number() || !std::isfinite(v.get<double>())) throw input_error(where, f, "must hold finite numbers");
    const double dl = x[0].get<double>(), db = x[1].get<double>(), dk = x[2].get<double>();
    const double n = x[3].get<double>(), r = x[4].get<double>();
    auto index_ok = [](double v, int size) { return v >= 0 && v < size && v == std::floor(v); };
    if (!index_ok(dl, c.rows) || !index_ok(db, c.range_bins) || !index_ok(dk, c.classes) || n < 0 || r < 0 || r > n)
      throw input_error(where, f, "row, bin or class out of range, or returns not within 0..cells");
    const int l = static_cast<int>(dl), b = static_cast<int>(db), k = static_cast<int>(dk);
    c.cells[c.index(l, b, k)] += n;
    c.returns[c.index(l, b, k)] += r;
  }
  ReturnModel m = fit(c, layout, number(j, "prior_strength", where));
  if (j.contains("multipliers")) {
    const auto& ms = j["multipliers"];
    if (!ms.is_array()) throw input_error(where, "multipliers", "must be an array of {key, factor}");
    for (const auto& x : ms) {
      if (!x.is_object() || !x.contains("key") || !x["key"].is_string() || !x.contains("factor") || !x["factor"].is_array())
        throw input_error(where, "multipliers", "each entry needs a string key and a factor array");
      ReturnMultiplier mu;
      mu.key = return_key_from_string(x["key"].get<std::string>(), where);
      const int n = return_key_size(mu.key, m.rows());
      if (static_cast<int>(x["factor"].size()) != n)
        throw input_error(where, "multipliers/factor", std::string(to_string(mu.key)) + " needs " + std::to_string(n) + " factors, got " +
                          std::to_string(x["factor"].size()));
      for (const auto& v : x["factor"]) {
        if (!v.is_number() || !(v.get<double>() >= 0) || !std::isfinite(v.get<double>()))
          throw input_error(where, "multipliers/factor", "factors must be finite and >= 0");
        mu.factor.push_back(v.get<float>());
      }
      if (x.contains("note") && x["note"].is_string()) mu.note = x["note"];
      m.multipliers.push_back(std::move(mu));
    }
  }
  if (j.contains("source") && j["source"].is_string()) m.source = j["source"];
  if (j.contains("fit_command") && j["fit_command"].is_string()) m.fit_command = j["fit_command"];
  if (j.contains("fit_places") && j["fit_places"].is_array())
    for (const auto& p : j["fit_places"]) m.fit_places.push_back(p.is_string() ? p.get<std::string>() : p.dump());
  return m;
}

ReturnModel ReturnModel::load(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw input_error(path, "(file)", "cannot open the return model file");
  std::stringstream ss;
  ss << in.rdbuf();
  json j;
  try {
    j = json::parse(ss.str());
  } catch (const json::exception& e) {
    throw input_error(path, "(document)", std::string("not valid JSON: ") + e.what());
  }
  return from_json(j, path);
}

void ReturnModel::save(const std::string& path) const {
  // One key per line and one count entry per line: readable, and a refit shows as a small diff.
  const json j = to_json();
  std::string text = "{\n";
  for (auto it = j.begin(); it != j.end(); ++it) {
    text += " " + json(it.key()).dump() + ": ";
    if (it.key() == "counts") {
      text += "[\n";
      for (std::size_t e = 0; e < it->size(); ++e) text += "  " + (*it)[e].dump() + (e + 1 < it->size() ? ",\n" : "\n");
      text += " ]";
    } else {
      text += it->dump();
    }
    text += std::next(it) != j.end() ? ",\n" : "\n";
  }
  write_file_atomically(path, text + "}\n");
}

double return_draw(std::uint64_t seed, std::uint64_t frame, std::uint64_t cell) {
  const std::uint64_t h = splitmix64(splitmix64(splitmix64(seed) ^ frame) ^ cell);
  return static_cast<double>(h >> 11) * 0x1.0p-53;
}

int apply_return_model(const ReturnModel& model, pgm::PolarGridMap& map, std::uint64_t seed, std::uint64_t frame) {
  if (map.rows() != model.rows())
    throw Error("return model: fitted for " + std::to_string(model.rows()) + " lasers (" + model.layout().name +
                "), the map has " + std::to_string(map.rows()) + " rows");
  const float* range = map.channel("range");
  const float* cls = map.channel("class");
  float* mask = map.channel("mask");
  const int C = static_cast<int>(map.channel_names().size());
  const int object_id = map.has_channel("object_id") ? map.channel_index("object_id") : -1;
  const int W = map.cols();
  int dropped = 0;
  for (std::size_t i = 0; i < map.cells(); ++i) {
    if (mask[i] < 0.5f) continue;
    const double p = model.probability_at(static_cast<int>(i / W), static_cast<int>(i % W), range[i], static_cast<int>(cls[i]));
    if (return_draw(seed, frame, i) < p) continue;
    ++dropped;
    for (int c = 0; c < C; ++c) map.channel(c)[i] = c == object_id ? -1.f : 0.f;
    map.point_index()[i] = -1;
  }
  return dropped;
}

}  // namespace lidarsim::sensor
