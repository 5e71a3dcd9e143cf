// lidar-qualify returns: the return model fitted on some places and scored on each place it never
// saw. A place is one drive / recording (--place NAME=FORMAT:DIR, repeated per folder); per held-out place:
//  - "same sensor": the laser x range x class table fitted on every other place of the same beam
//    layout (per-laser rates only carry over between units of one sensor model);
//  - "laser-free": the range x class table fitted on every other place, any sensor;
//  - the baseline "every geometry cell returns".
// The table has no spatial context and never sees a held-out scan, so the split cannot leak;
// the held-out target (pgm::return_target) is computed from the held-out scan alone.
#include <cxxopts.hpp>

#include <algorithm>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <sstream>

#include "common/atomic_file.h"
#include "common/error.h"
#include "pgm/materials.h"
#include "qualify/returns/returns.h"
#include "qualify/returns/returns_places.h"

namespace lidarsim::qualify {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

sensor::ReturnModel fit_on(const std::vector<const ReturnPlace*>& places, const pgm::BeamLayout& layout, bool per_laser,
                           double prior) {
  // The laser-free chain ignores rows, so places of other sensors pool into row 0.
  sensor::ReturnCounts counts(per_laser ? layout.rows() : 1, pgm::class_count());
  for (const ReturnPlace* p : places)
    for (const auto& t : p->targets) {
      if (per_laser) {
        counts.add(t);
        continue;
      }
      for (std::size_t i = 0; i < t.label.size(); ++i)
        if (t.label[i] != pgm::ReturnLabel::Sky) counts.add(0, t.range[i], t.class_id[i], t.label[i] == pgm::ReturnLabel::Return);
    }
  pgm::BeamLayout fit_layout = layout;
  if (!per_laser) fit_layout = pgm::BeamLayout::from_elevations_deg("laser-free", {0.0}, layout.columns);
  sensor::ReturnModel m = sensor::ReturnModel::fit(counts, fit_layout, prior);
  for (const ReturnPlace* p : places) m.fit_places.push_back(p->name);
  return m;
}

std::string f3(double v) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(3) << v;
  return s.str();
}

json held_out_entry(const std::string& model, const std::vector<std::string>& trained_on, const ReturnScore& s) {
  json j = to_json(s);
  j["model"] = model;
  j["trained_on"] = trained_on;
  return j;
}

// One held-out place: its cells by rule, and a row per model (same sensor, laser-free, baseline)
// in the report, the Markdown table and the printed table.
json held_out_place(const ReturnPlace& held, const std::vector<ReturnPlace>& places, double prior, std::string& md) {
  json e;
  e["place"] = held.name;
  e["format"] = held.format;
  e["sensor"] = held.layout.name;
  e["rows"] = held.layout.rows();
  e["scans"] = held.targets.size();
  long long by_rule[static_cast<int>(pgm::ReturnRule::count)] = {};
  for (const auto& t : held.targets)
    for (int r = 0; r < static_cast<int>(pgm::ReturnRule::count); ++r) by_rule[r] += t.by_rule[r];
  for (int r = 0; r < static_cast<int>(pgm::ReturnRule::count); ++r)
    e["cells_by_rule"][pgm::to_string(static_cast<pgm::ReturnRule>(r))] = by_rule[r];
  e["sensor_height_m"] = held.heights;
  std::vector<const ReturnPlace*> same, others;
  std::vector<std::string> same_names, other_names;
  for (const auto& p : places)
    if (&p != &held) {
      others.push_back(&p);
      other_names.push_back(p.name);
      if (p.layout == held.layout) same.push_back(&p), same_names.push_back(p.name);
    }
  std::vector<std::pair<std::string, json>> rows;
  const ReturnScore base = score_returns(held.targets, nullptr, false);
  if (!same.empty()) {
    const auto m = fit_on(same, held.layout, true, prior);
    rows.emplace_back("same sensor", held_out_entry("same sensor: laser x range x class", same_names, score_returns(held.targets, &m, true)));
  }
  {
    const auto m = fit_on(others, held.layout, false, prior);
    rows.emplace_back("laser-free", held_out_entry("laser-free: range x class", other_names, score_returns(held.targets, &m, false)));
  }
  rows.emplace_back("baseline", held_out_entry("baseline: every geometry cell returns", {}, base));
  for (const auto& [label, r] : rows) {
    e["models"].push_back(r);
    std::string trained;
    for (const auto& n : r["trained_on"]) trained += (trained.empty() ? "" : ", ") + n.get<std::string>();
    md += "| " + held.name + " | " + held.layout.name + " | " + std::to_string(held.targets.size()) + " | " +
          std::to_string(base.cells) + " | " + std::to_string(by_rule[1]) + " / " + std::to_string(by_rule[2]) + " / " +
          std::to_string(by_rule[3]) + " | " + f3(base.measured_rate) + " | " + label + " | " +
          (trained.empty() ? "-" : trained) + " | " + f3(r["auroc"]) + " | " + f3(r["tv_laser"]) + " | " +
          f3(r["tv_range_5m"]) + " | " + f3(r["tv_class"]) + " | " + f3(r["tv_laser_halves"]) + " / " +
          f3(r["tv_range_5m_halves"]) + " / " + f3(r["tv_class_halves"]) + " |\n";
    std::cout << std::setw(16) << held.name << std::setw(34) << r["model"].get<std::string>().substr(0, 33) << "  "
              << f3(r["auroc"]) << "  " << f3(r["tv_laser"]) << "   " << f3(r["tv_range_5m"]) << "   "
              << f3(r["tv_class"]) << "   (" << f3(r["tv_laser_halves"]) << " " << f3(r["tv_range_5m_halves"]) << " "
              << f3(r["tv_class_halves"]) << ")\n";
  }
  return e;
}

// --out-model: the laser x range x class table fitted on every place of one sensor.
json write_model(const std::vector<ReturnPlace>& places, const std::string& sensor, double prior,
                 const std::string& command, const std::string& path) {
  std::vector<const ReturnPlace*> fit;
  for (const auto& p : places)
    if (p.layout.name == sensor) fit.push_back(&p);
  if (fit.empty()) throw Error("--model-sensor: no place has the beam layout \"" + sensor + "\"");
  for (const ReturnPlace* p : fit)
    if (!(p->layout == fit.front()->layout))
      throw Error("--model-sensor: places named " + sensor + " differ in layout (" + p->layout.difference(fit.front()->layout) + ")");
  sensor::ReturnModel m = fit_on(fit, fit.front()->layout, true, prior);
  for (const ReturnPlace* p : fit)
    for (const auto& d : p->dirs) m.source += (m.source.empty() ? "" : "; ") + p->name + "=" + p->format + ":" + d.string();
  m.fit_command = command;
  m.save(path);
  std::cout << "wrote " << path << " (fitted on";
  for (const auto& n : m.fit_places) std::cout << " " << n;
  std::cout << ")\n";
  return {{"path", path}, {"fit_places", m.fit_places}};
}

}  // namespace

int run_returns(int argc, char** argv) {
  cxxopts::Options opts("lidar-qualify returns",
                        "Return model (raydrop): per held-out place, fit on the others and score AUROC and the total\n"
                        "variation of return rates per laser, 5 m range bin and class (docs/returns.md).");
  opts.add_options()
    ("place", "a place: NAME=FORMAT:DIR, FORMAT semantickitti | kitti_object | rellis3d | nuscenes_lidarseg (repeat; a NAME given again adds a folder to that place)", cxxopts::value<std::vector<std::string>>())
    ("out", "report folder (report.json, report.md)", cxxopts::value<std::string>())
    ("out-model", "write the table fitted on every place of --model-sensor here (JSON)", cxxopts::value<std::string>())
    ("model-sensor", "beam layout name of the places --out-model is fitted on (default: the first place's)", cxxopts::value<std::string>())
    ("prior", "pseudo-cells with which each table entry is shrunk towards its coarser margin", cxxopts::value<double>()->default_value("20"))
    ("sensor-height", "sensor height above the ground, m (default: estimated per scan)", cxxopts::value<double>()->default_value("0"))
    ("row-gap", "return target: most columns between two returns that bracket a drop", cxxopts::value<int>()->default_value("6"))
    ("h,help", "this help");
  const auto a = opts.parse(argc, argv);
  if (a.count("help")) {
    std::cout << opts.help() << "\n";
    return 0;
  }
  if (!a.unmatched().empty()) throw Error("returns: unexpected argument \"" + a.unmatched().front() + "\"");
  if (!a.count("place") || a["place"].as<std::vector<std::string>>().size() < 2)
    throw Error("returns: give at least two --place NAME=FORMAT:DIR (one is held out, the others fit)");
  if (!a.count("out")) throw Error("returns: --out DIR is required");
  const double prior = a["prior"].as<double>();
  pgm::ReturnTargetOptions rule;
  rule.sensor_height_m = a["sensor-height"].as<double>();
  rule.row_gap = a["row-gap"].as<int>();
  if (rule.row_gap < 0) throw Error("--row-gap: must be >= 0");

  std::vector<ReturnPlace> places = parse_return_places(a["place"].as<std::vector<std::string>>());
  if (places.size() < 2) throw Error("returns: give at least two places (one is held out, the others fit)");
  for (auto& p : places) {
    load_return_place(p, rule);
    std::cerr << "place " << p.name << ": " << p.targets.size() << " scans (" << p.layout.name << ", "
              << p.layout.rows() << " rows)\n";
  }

  std::string command = "lidar-qualify";
  for (int i = 0; i < argc; ++i) command += std::string(" ") + argv[i];
  json report;
  report["command"] = command;
  report["prior_strength"] = prior;
  report["rule"] = {{"row_gap", rule.row_gap}, {"similar_range", rule.similar_range},
                    {"ground_reach_share", rule.ground_reach_share}, {"reach_quantile", rule.reach_quantile},
                    {"sensor_height_m", rule.sensor_height_m}};
  std::string md = "# Return model, held out by place\n\nCommand: `" + command +
                   "`\n\nPer held-out place: the table fitted on the other places (same sensor: laser x 5 m range x "
                   "class; laser-free: 5 m range x class on every other place), scored on the held-out place's geometry "
                   "cells. TV = sum over groups of share x |predicted - measured rate|; halves = the same between two "
                   "halves of the measured cells (alternating 32-column sectors).\n\n"
                   "| held out | sensor | scans | geometry cells | drops (row gap / below / ground) | measured rate | model | trained on | "
                   "AUROC | TV laser | TV range | TV class | halves: laser / range / class |\n"
                   "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  std::cout << std::left << std::setw(16) << "held out" << std::setw(34) << "model" << "  AUROC  TVlaser TVrange TVclass  (halves)\n";
  for (const auto& held : places) report["held_out"].push_back(held_out_place(held, places, prior, md));

  if (a.count("out-model")) {
    const std::string sensor = a.count("model-sensor") ? a["model-sensor"].as<std::string>() : places.front().layout.name;
    report["model"] = write_model(places, sensor, prior, command, a["out-model"].as<std::string>());
  }
  const fs::path out = a["out"].as<std::string>();
  fs::create_directories(out);
  write_file_atomically(out / "report.json", report.dump(2) + "\n");
  write_file_atomically(out / "report.md", md);
  std::cout << "wrote " << (out / "report.md") << "\n";
  return 0;
}

}  // namespace lidarsim::qualify
