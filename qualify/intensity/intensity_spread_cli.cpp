// lidar-qualify loop intensity-spread: the closed loop on the spread of intensity of one place's
// labelled scans (qualify/intensity/intensity_spread_loop.h).
//   lidar-qualify loop intensity-spread --semantickitti DIR --report R.json [--rounds 1] [--model CK.h5]
//       [--base-terms laser,...] [--folds 4] [--sectors 64] [--guard-deg 0.5] [--min-gain 0.002]
// --rounds N reruns the loop with each added term in the base until nothing more is added.
#include <cxxopts.hpp>

#include <filesystem>
#include <iostream>

#include "common/atomic_file.h"
#include "common/error.h"
#include "infer/intensity_spread_terms.h"
#include "qualify/intensity/intensity.h"
#include "qualify/intensity/intensity_spread_loop.h"
#include "qualify/range_noise/loop_rounds.h"

namespace lidarsim::qualify {

namespace fs = std::filesystem;

namespace {

cxxopts::Options intensity_spread_cli_options() {
  cxxopts::Options opts("lidar-qualify loop intensity-spread",
                        "The closed loop on the spread of intensity: log|measured - out-of-fold class x range lookup| "
                        "against every feature, held out on rotated azimuth folds with guard bands (docs/intensity.md).");
  opts.add_options()
    ("semantickitti", "labelled scans: SemanticKITTI (velodyne + labels) or a KITTI object folder", cxxopts::value<std::string>())
    ("model", "a checkpoint with a spread head: the residual against its mean, its spread the base (scans of places it did not train on)", cxxopts::value<std::string>())
    ("spread-terms", "with --model: terms its spread carries already (a previous run's --out-terms)", cxxopts::value<std::string>())
    ("out-terms", "with --model: the terms its spread needs (the given ones, the range level and the last round's), for lidar-infer --spread-terms", cxxopts::value<std::string>())
    ("split", "the intensity folds' split of the columns", cxxopts::value<std::string>()->default_value("guarded"))
    ("intensity-folds", "rotated guarded folds for the out-of-fold mean (1 or 4)", cxxopts::value<int>()->default_value("4"))
    ("report", "report JSON (a Markdown beside it)", cxxopts::value<std::string>())
    ("h,help", "this help");
  add_loop_round_options(opts);
  return opts;
}

}  // namespace

int run_loop_intensity_spread(int argc, char** argv) {
  cxxopts::Options opts = intensity_spread_cli_options();
  const auto a = opts.parse(argc, argv);
  if (a.count("help")) {
    std::cout << opts.help() << "\n";
    return 0;
  }
  if (!a.unmatched().empty()) throw Error("loop intensity-spread: unexpected argument \"" + a.unmatched().front() + "\"");
  if (!a.count("semantickitti")) throw Error("--semantickitti: required (the labelled scans)");
  if (!a.count("report")) throw Error("--report: required (the loop's report JSON)");
  IntensitySpreadOptions o;
  o.split = a["split"].as<std::string>(), o.folds = a["intensity-folds"].as<int>();
  if (a.count("model")) o.model = a["model"].as<std::string>();
  if ((a.count("spread-terms") || a.count("out-terms")) && !a.count("model"))
    throw Error("--spread-terms, --out-terms: need --model (terms on a checkpoint's spread head)");
  if (a.count("spread-terms")) o.spread_terms = infer::load_intensity_spread_terms(a["spread-terms"].as<std::string>()).terms;
  o.loop = loop_options_from(a);
  const std::string dir = a["semantickitti"].as<std::string>();
  const data::Dataset ds = import_for_qualify(dir);
  std::string command = "lidar-qualify loop intensity-spread";
  for (int i = 1; i < argc; ++i) command += std::string(" ") + argv[i];
  nlohmann::json report = {{"command", command}, {"data", dir}, {"rounds", nlohmann::json::array()},
                           {"base", o.model.empty() ? "the class x range lookup's out-of-fold mean; spread: a log-scale per 5 m range bin"
                                                    : "the checkpoint " + o.model + ": its mean and its spread head"}};
  std::string md;
  const RangeLoopResult r = run_loop_rounds(
      a, o.loop, [&](const RangeLoopOptions& lo) { IntensitySpreadOptions x = o; x.loop = lo; return loop_intensity_spread(ds, x); },
      [&](const RangeLoopResult& x) { return intensity_spread_json(x, !o.model.empty()); }, command, "intensity spread", "returns", report, md);
  const fs::path out = a["report"].as<std::string>();
  if (out.has_parent_path()) fs::create_directories(out.parent_path());
  write_file_atomically(out, report.dump(2) + "\n");
  fs::path md_path = out;
  md_path.replace_extension(".md");
  write_file_atomically(md_path, md);
  std::cout << "wrote " << out.string() << "\n";
  if (a.count("out-terms")) {
    // The model's spread times: the terms it had, its range level, the base terms and the added one.
    infer::IntensitySpreadTerms t;
    t.source = command;
    t.terms = o.spread_terms;
    t.terms.push_back(r.range_level);
    for (const auto& x : r.terms) t.terms.push_back(x);
    const fs::path tp = a["out-terms"].as<std::string>();
    if (tp.has_parent_path()) fs::create_directories(tp.parent_path());
    write_file_atomically(tp, infer::intensity_spread_terms_json(t));
    std::cout << "wrote " << tp.string() << " (" << t.terms.size() << " terms)\n";
  }
  return 0;
}

}  // namespace lidarsim::qualify
