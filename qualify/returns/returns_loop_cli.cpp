// lidar-qualify loop returns: the closed loop on the return rate of one measured place (the
// target), against the return model fitted on reference places (qualify/returns/returns_loop.h).
//   lidar-qualify loop returns --place NAME=FORMAT:DIR ... --target NAME --report R.json
//                              [--reference NAME,NAME | self] [--folds 5] [--min-gain 0.002]
// Places are given as `lidar-qualify returns` takes them (a NAME given again adds a folder).
#include <cxxopts.hpp>

#include <algorithm>
#include <filesystem>
#include <iostream>
#include <sstream>

#include "common/atomic_file.h"
#include "common/error.h"
#include "qualify/returns/returns_loop.h"
#include "qualify/returns/returns_places.h"

namespace lidarsim::qualify {

namespace fs = std::filesystem;

namespace {

// --target: one place (folds = its scans) or several, comma-separated (folds = whole places with
// --folds-by place: no scenery is shared).
std::vector<ReturnPlace*> named_targets(std::vector<ReturnPlace>& places, const std::string& names) {
  std::vector<ReturnPlace*> targets;
  std::stringstream ss(names);
  for (std::string n; std::getline(ss, n, ',');) {
    auto it = std::find_if(places.begin(), places.end(), [&](const ReturnPlace& p) { return p.name == n; });
    if (it == places.end()) throw Error("--target " + n + ": not among the --place names");
    targets.push_back(&*it);
  }
  return targets;
}

// --reference: the named places, none for `self` (each fold's base then sees the target's fit
// scans only), and by default every other place of the target's beam layout.
std::vector<const ReturnPlace*> reference_places(const std::vector<ReturnPlace>& places,
                                                 const std::vector<ReturnPlace*>& targets, const std::string& names) {
  const ReturnPlace& first = *targets.front();
  auto is_target = [&](const ReturnPlace& p) { return std::find(targets.begin(), targets.end(), &p) != targets.end(); };
  std::vector<const ReturnPlace*> refs;
  if (!names.empty() && names != "self") {
    std::stringstream ss(names);
    for (std::string n; std::getline(ss, n, ',');) {
      auto it = std::find_if(places.begin(), places.end(), [&](const ReturnPlace& p) { return p.name == n; });
      if (it == places.end()) throw Error("--reference " + n + ": not among the --place names");
      if (is_target(*it)) throw Error("--reference " + n + ": also a --target (use --reference self)");
      if (!(it->layout == first.layout)) throw Error("--reference " + n + ": another beam layout than the target's (" + it->layout.name + ")");
      refs.push_back(&*it);
    }
  } else if (names.empty()) {
    for (const auto& p : places)
      if (!is_target(p) && p.layout == first.layout) refs.push_back(&p);
  }
  return refs;
}

// The report (JSON, Markdown beside it) and the printed summary.
void write_loop_report(const ReturnLoopResult& r, const std::string& command, const std::string& target_names,
                       bool folds_are_places, const std::vector<std::string>& ref_names, const fs::path& report) {
  nlohmann::json j = to_json(r);
  j["command"] = command;
  j["target"] = target_names;
  j["folds_are"] = folds_are_places ? "whole places" : "scans";
  j["reference"] = ref_names;
  if (report.has_parent_path()) fs::create_directories(report.parent_path());
  write_file_atomically(report, j.dump(2) + "\n");
  fs::path md = report;
  md.replace_extension(".md");
  std::string text = to_markdown(r, command);
  text += "\nTarget: " + target_names + "; base fitted on:";
  for (const auto& n : ref_names) text += " " + n;
  write_file_atomically(md, text + "\n");
  std::cout << "target " << target_names << ": " << r.scans << " scans, " << r.cells << " geometry cells\n"
            << "held-out deviance " << r.deviance_before << " -> " << r.deviance_after << ", added: "
            << (r.added_feature.empty() ? "nothing" : r.added_feature) << "\n";
  for (const auto& c : r.candidates)
    std::cout << "  " << c.feature << " " << to_string(c.form) << ": cut " << c.score << " (bound " << c.selection_lower << ") "
              << c.decision << "\n";
  std::cout << "wrote " << report << " and " << md << "\n";
}

}  // namespace

int run_loop_returns(int argc, char** argv) {
  cxxopts::Options opts("lidar-qualify loop returns",
                        "The closed loop on the return rate: residuals of returned / not returned against every feature,\n"
                        "judged on held-out scans of the target place (docs/returns.md).");
  opts.add_options()
    ("place", "a place: NAME=FORMAT:DIR (repeat; a NAME given again adds a folder)", cxxopts::value<std::vector<std::string>>())
    ("target", "the place(s) examined, comma-separated: one place (folds = its scans) or several (folds = whole places)", cxxopts::value<std::string>())
    ("reference", "places the base is fitted on, comma-separated, or `self` (the target's own fit scans); default: every other place of the target's beam layout, else self", cxxopts::value<std::string>())
    ("report", "loop report JSON (Markdown beside it)", cxxopts::value<std::string>())
    ("out-model", "write the base fitted on every reference cell, with the added multiplier, here (return model JSON)", cxxopts::value<std::string>())
    ("folds-by", "several --target places: scan (folds = scans of every place) | place (whole places)", cxxopts::value<std::string>()->default_value("scan"))
    ("folds", "folds", cxxopts::value<int>()->default_value("5"))
    ("min-gain", "smallest held-out deviance cut (share of the base's) that is added", cxxopts::value<double>()->default_value("0.002"))
    ("h,help", "this help");
  const auto a = opts.parse(argc, argv);
  if (a.count("help")) {
    std::cout << opts.help() << "\n";
    return 0;
  }
  if (!a.unmatched().empty()) throw Error("loop returns: unexpected argument \"" + a.unmatched().front() + "\"");
  if (!a.count("place")) throw Error("loop returns: give the places with --place NAME=FORMAT:DIR");
  if (!a.count("report")) throw Error("loop returns: --report R.json is required");
  std::vector<ReturnPlace> places = parse_return_places(a["place"].as<std::vector<std::string>>());
  std::vector<ReturnPlace*> targets =
      named_targets(places, a.count("target") ? a["target"].as<std::string>() : places.front().name);
  if (targets.empty()) throw Error("--target: no place named");
  for (auto& p : places) load_return_place(p);
  const ReturnPlace& first = *targets.front();
  for (const ReturnPlace* t : targets)
    if (!(t->layout == first.layout)) throw Error("--target " + t->name + ": another beam layout than " + first.name + "'s");
  const std::vector<const ReturnPlace*> refs =
      reference_places(places, targets, a.count("reference") ? a["reference"].as<std::string>() : "");
  const std::string folds_by = a["folds-by"].as<std::string>();
  if (folds_by != "scan" && folds_by != "place") throw Error("--folds-by: expected scan or place, got \"" + folds_by + "\"");
  ReturnLoopOptions o;
  std::vector<ReturnCell> cells, ref_cells;
  int scan = 0;
  std::string target_names;
  for (std::size_t g = 0; g < targets.size(); ++g) {
    target_names += (g ? "," : "") + targets[g]->name;
    for (const auto& t : targets[g]->targets) {
      if (targets.size() > 1 && a["folds-by"].as<std::string>() == "place") o.scan_group.push_back(static_cast<int>(g));
      auto c = return_cells(t, first.layout, scan++);
      cells.insert(cells.end(), c.begin(), c.end());
    }
  }
  std::vector<std::string> ref_names;
  if (refs.empty()) {
    ref_cells = cells;  // self: each fold's base sees only the fit scans
    ref_names.push_back(target_names + " (fit scans of each fold)");
  }
  for (const ReturnPlace* p : refs) {
    ref_names.push_back(p->name);
    for (const auto& t : p->targets) {
      auto c = return_cells(t, p->layout, scan++);
      ref_cells.insert(ref_cells.end(), c.begin(), c.end());
    }
  }
  o.folds = a["folds"].as<int>();
  o.min_gain = a["min-gain"].as<double>();
  const ReturnLoopResult r = loop_returns(cells, ref_cells, first.layout, o);

  std::string command = "lidar-qualify loop";
  for (int i = 0; i < argc; ++i) command += std::string(" ") + argv[i];
  if (a.count("out-model")) {
    sensor::ReturnModel m = r.model;
    m.fit_command = command;
    m.fit_places = ref_names;
    m.source = "lidar-qualify loop returns on " + target_names;
    m.save(a["out-model"].as<std::string>());
    std::cout << "wrote " << a["out-model"].as<std::string>() << "\n";
  }
  write_loop_report(r, command, target_names, !o.scan_group.empty(), ref_names, a["report"].as<std::string>());
  return 0;
}

}  // namespace lidarsim::qualify
