// lidar-qualify loop range-noise: the closed loop on the range noise of one place's labelled
// scans (qualify/range_noise/range_noise_loop.h), its own scans as the reference (each fold's base
// sees only the fit sectors).
//   lidar-qualify loop range-noise --semantickitti DIR --report R.json [--out-model M.json]
//       [--rounds 1] [--base-terms class,...] [--folds 4] [--sectors 64] [--guard-deg 0.5]
// --rounds N reruns the loop with each added term in the base until nothing more is added.
#include <cxxopts.hpp>

#include <algorithm>
#include <filesystem>
#include <iostream>

#include "common/atomic_file.h"
#include "common/error.h"
#include "qualify/range_noise/range_noise_cli.h"
#include "qualify/range_noise/loop_rounds.h"
#include "qualify/range_noise/range_noise_loop.h"

namespace lidarsim::qualify {

namespace fs = std::filesystem;

namespace {

cxxopts::Options loop_options() {
  cxxopts::Options opts("lidar-qualify loop range-noise",
                        "The closed loop on range noise: log-scale of local-fit residuals against every feature, held out "
                        "on rotated azimuth folds with guard bands (docs/range-noise.md).");
  opts.add_options()
    ("semantickitti", "SemanticKITTI folder (velodyne + labels; HDL-64E)", cxxopts::value<std::string>())
    ("nuscenes-lidarseg", "nuScenes-lidarseg folder; needs --sensor and --class-table", cxxopts::value<std::string>())
    ("sensor", "beam layout JSON (default for SemanticKITTI: the built-in HDL-64E)", cxxopts::value<std::string>())
    ("class-table", "foreign ontology -> ours (data/ontologies/*.csv)", cxxopts::value<std::string>())
    ("max-scans", "at most this many scans (0: all)", cxxopts::value<int>()->default_value("0"))
    ("report", "report JSON (a Markdown beside it)", cxxopts::value<std::string>())
    ("out-model", "range-noise model with the terms (version 2 when it has any)", cxxopts::value<std::string>())
    ("h,help", "this help");
  add_loop_round_options(opts);
  return opts;
}

}  // namespace

int run_loop_range_noise(int argc, char** argv) {
  cxxopts::Options opts = loop_options();
  const auto a = opts.parse(argc, argv);
  if (a.count("help")) {
    std::cout << opts.help() << "\n";
    return 0;
  }
  if (!a.unmatched().empty()) throw Error("loop range-noise: unexpected argument \"" + a.unmatched().front() + "\"");
  if (a.count("semantickitti") + a.count("nuscenes-lidarseg") != 1)
    throw Error("loop range-noise: give exactly one of --semantickitti, --nuscenes-lidarseg");
  if (!a.count("report")) throw Error("--report: required (the loop's report JSON)");
  const std::string dataset = a.count("semantickitti") ? "semantickitti" : "nuscenes-lidarseg";
  const std::string dir = a[dataset].as<std::string>();
  if (dataset != "semantickitti" && (!a.count("sensor") || !a.count("class-table")))
    throw Error("--sensor, --class-table: required for --nuscenes-lidarseg");
  const pgm::BeamLayout layout = a.count("sensor") ? pgm::BeamLayout::from_file(a["sensor"].as<std::string>()) : pgm::BeamLayout::hdl64e();
  RangeLoopOptions o = loop_options_from(a);
  const auto scans = read_labelled_scans(dataset, dir, a.count("class-table") ? a["class-table"].as<std::string>() : "",
                                         a["max-scans"].as<int>());
  std::vector<LoopResidual> target;
  for (std::size_t s = 0; s < scans.size(); ++s) {
    auto r = loop_residuals(scans[s].points, layout, static_cast<int>(s), scans[s].source);
    target.insert(target.end(), r.begin(), r.end());
  }
  std::string command = "lidar-qualify";
  for (int i = 0; i < argc; ++i) command += std::string(" ") + (i == 0 ? "loop range-noise" : argv[i]);
  nlohmann::json report = {{"command", command}, {"data", dir}, {"rounds", nlohmann::json::array()}};
  std::string md;
  const RangeLoopResult r = run_loop_rounds(
      a, o, [&](const RangeLoopOptions& lo) { return loop_range_noise(target, target, lo); },
      [](const RangeLoopResult& x) { return to_json(x); }, command, "range noise", "residuals", report, md);
  const fs::path out = a["report"].as<std::string>();
  if (out.has_parent_path()) fs::create_directories(out.parent_path());
  write_file_atomically(out, report.dump(2) + "\n");
  fs::path md_path = out;
  md_path.replace_extension(".md");
  write_file_atomically(md_path, md);
  if (a.count("out-model")) {
    sensor::RangeNoiseModel m = r.model;
    m.sensor = layout.name;
    m.source = "lidar-qualify loop range-noise on " + std::to_string(scans.size()) + " scans of " + dir + ": " + command;
    const fs::path mp = a["out-model"].as<std::string>();
    if (mp.has_parent_path()) fs::create_directories(mp.parent_path());
    write_file_atomically(mp, sensor::range_noise_model_json(m));
    std::cout << "wrote " << mp.string() << " (" << m.terms.size() << " terms)\n";
  }
  std::cout << "wrote " << out.string() << "\n";
  return 0;
}

}  // namespace lidarsim::qualify
