// lidar-qualify: qualify the simulation against measured data, and close the loop.
//   lidar-qualify objects   --kitti-tracking DIR --model M.json --out R
//   lidar-qualify intensity --model CK.h5 --semantickitti DIR --out R
//   lidar-qualify loop objects   --kitti-tracking DIR --report R.json
//   lidar-qualify loop intensity --semantickitti DIR --report R.json [--base unet|lookup]
#include <cxxopts.hpp>

#include <filesystem>
#include <iostream>
#include <string>

#include "common/atomic_file.h"
#include "common/error.h"
#include "qualify/intensity/intensity.h"
#include "qualify/intensity/intensity_spread_loop.h"
#include "qualify/objects/object_false_positives.h"
#include "qualify/objects/objects.h"
#include "qualify/range_noise/range_noise_cli.h"
#include "qualify/range_noise/range_noise_loop.h"
#include "qualify/report.h"
#include "qualify/returns/returns.h"
#include "qualify/returns/returns_loop.h"
#include "sensor/kpi_model.h"

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

const char* kUsage =
    "usage:\n"
    "  lidar-qualify objects   --kitti-tracking DIR --model M.json --out R [--nested] [--held-out-seeds N]  KPI model vs measured detections\n"
    "  lidar-qualify intensity --model CK.h5 --semantickitti DIR --out R        predicted vs measured intensity\n"
    "  lidar-qualify loop objects   --kitti-tracking DIR --report R.json        residual -> effect -> refit\n"
    "  lidar-qualify loop intensity --semantickitti DIR --report R.json [--base unet|lookup|lookup-beam] [--folds 1|4] [--out-model CK.h5]\n"
    "  lidar-qualify range-noise --semantickitti DIR --out M.json              range noise fitted on measured scans\n"
    "  lidar-qualify loop range-noise --semantickitti DIR --report R.json [--out-model M.json] [--rounds N]\n"
    "  lidar-qualify loop intensity-spread --semantickitti DIR --report R.json [--model CK.h5] [--rounds N]\n"
    "  lidar-qualify returns   --place NAME=FORMAT:DIR ... --out R [--out-model M.json]   return model held out by place\n"
    "add --help after a command for its options\n";

std::string need(const cxxopts::ParseResult& a, const std::string& key, const std::string& what) {
  if (!a.count(key)) throw Error("--" + key + ": required (" + what + ")");
  return a[key].as<std::string>();
}

void print_loop(const nlohmann::json& j) {
  std::cout << "domain " << j["domain"].get<std::string>() << "; metric: " << j["metric"].get<std::string>() << "\n";
  std::cout << "ranking (held-out share of residual variance explained):\n";
  for (const auto& r : j["ranking"])
    std::cout << "  " << r["feature"].get<std::string>() << "  " << r["score"].get<double>()
              << (r.contains("target") ? "  (" + r["target"].get<std::string>() + ")" : std::string()) << "\n";
  std::cout << "added effect: " << (j["added_effect"].is_null() ? "none (no feature stands out)" : j["added_effect"].get<std::string>())
            << "\nbefore " << j["before"].get<double>() << "  after " << j["after"].get<double>() << "\n";
  if (j.contains("candidates"))  // the object loop: why each added form was added
    for (const auto& c : j["candidates"])
      if (c["decision"] == "added" && c.contains("reason"))
        std::cout << "  " << c["feature"].get<std::string>() << " " << c["kind"].get<std::string>() << " on "
                  << c["target"].get<std::string>() << ": " << c["reason"].get<std::string>() << "\n";
  if (j.contains("rejected_effect"))
    std::cout << "tried and rejected " << j["rejected_effect"]["feature"].get<std::string>() << ": "
              << j["rejected_effect"]["why"].get<std::string>() << "\n";
  if (j.contains("seeds_before"))
    std::cout << "per seed: before " << j["seeds_before"].dump() << "  after " << j["seeds_after"].dump() << "\n";
  if (j.contains("rounds"))
    for (const auto& r : j["rounds"])
      std::cout << "round: added " << (r["added_effect"].is_null() ? "nothing" : r["added_effect"].get<std::string>())
                << " (top " << r["top"]["feature"].get<std::string>() << ")  before " << r["before"].get<double>()
                << "  after " << r["after"].get<double>() << "\n";
  if (j.contains("held_out_tracks"))
    std::cout << "held-out tracks better with it: " << j["held_out_tracks_better"].get<int>() << " of "
              << j["held_out_tracks"].get<int>() << "; 95% interval of the change "
              << j["change_interval95"].dump() << "\n";
  if (j.contains("folds"))
    for (const auto& f : j["folds"])
      std::cout << "fold: fit " << f["fit_sequences"].dump() << ", judged on " << f["held_out_sequences"].dump()
                << ": before " << f["before"].get<double>() << "  after " << f["after"].get<double>() << "\n";
  if (j.contains("after_simulated") && !j["after_simulated"].is_null())
    std::cout << "re-simulated through the KPI manager: before " << j["before_simulated"].get<double>() << "  after "
              << j["after_simulated"].get<double>() << "\n";
  if (j.contains("added_effects") && j["added_effects"].size() > 1) {
    std::cout << "every effect added (one per target):\n";
    for (const auto& e : j["added_effects"]) {
      std::cout << "  " << e["feature"].get<std::string>() << " on " << e["target"].get<std::string>() << ": held-out "
                << e["before"].get<double>() << " -> " << e["after"].get<double>();
      if (!e["after_simulated"].is_null())
        std::cout << ", re-simulated " << e["before_simulated"].get<double>() << " -> "
                  << e["after_simulated"].get<double>();
      std::cout << "\n";
    }
  }
}

cxxopts::Options command_options(const std::string& name) {
  cxxopts::Options opts(name, "qualification against measured data");
  opts.add_options()
    ("kitti-tracking", "KITTI tracking folder (label_02/, calib/, detection/<det>_<Class>_val/)", cxxopts::value<std::string>())
    ("seqmap", "sequence list (default DIR/evaluate_tracking.seqmap.val if present, else every label_02 file)", cxxopts::value<std::string>()->default_value(""))
    ("detector", "detection folder prefix", cxxopts::value<std::string>()->default_value("pointrcnn"))
    ("semantickitti", "SemanticKITTI folder (sequences/NN/velodyne, labels); loop intensity also takes a KITTI object folder (velodyne, label_2, calib) with --split frames:...", cxxopts::value<std::string>())
    ("model", "KPI model JSON (objects) or checkpoint (intensity)", cxxopts::value<std::string>())
    ("out", "report folder (report.json, report.md, PNGs)", cxxopts::value<std::string>())
    ("report", "loop report JSON", cxxopts::value<std::string>())
    ("max-effects", "loop objects: bias forms added per run, at most one per target, best first (0: no limit)", cxxopts::value<int>()->default_value("0"))
    ("out-model", "loop: write the refitted model here (objects: KPI model JSON with the added conditional term; intensity: the UNet checkpoint with the added channel or per-row affine layer)", cxxopts::value<std::string>())
    ("term-shrink", "objects, loop objects: shrink the loop's bias terms by their track-bootstrap uncertainty on the fit sequences: off | zero (every table towards 0) | pooled (the pooled table towards 0, each class's towards it)", cxxopts::value<std::string>()->default_value("off"))
    ("pool-track-spread", "objects, loop objects: the base model's per-track size constants partially pooled across classes (a class with few tracks borrows the others' ratio to the within-track noise)")
    ("nested", "objects: also score the loop's model nested (the loop run on each outer fold's fit sequences only)")
    ("base", "loop intensity: base model, unet (retrained with the effect as a new channel), lookup (class x 5 m range) or lookup-beam (+ an offset per beam row)", cxxopts::value<std::string>()->default_value("unet"))
    ("folds", "loop intensity: 1 (the guarded split's regions) or 4 (rotated so every column is validated once); default 4 for a lookup base, 1 for unet", cxxopts::value<int>()->default_value("0"))
    ("steps", "loop intensity: training steps per UNet", cxxopts::value<int>()->default_value("1000"))
    ("lookup-base", "loop intensity --base unet: the UNets learn the residual over the class x 5 m range + per-beam lookup (lidar-train --lookup-base=classes)")
    ("seeds", "loop intensity: UNets per model (seeds 1..n), averaged", cxxopts::value<int>()->default_value("2"))
    ("threads", "loop intensity: OpenMP threads", cxxopts::value<int>()->default_value("2"))
    ("split", "loop intensity: guarded (guard bands of twice the UNet's receptive field) | interleaved (leaks; for comparison) | guarded:<half-width> | frames:<id>,... (whole frames held out)", cxxopts::value<std::string>()->default_value("guarded"))
    ("quiet", "no progress on stderr")
    ("threshold", "loop: held-out share of residual variance below which no effect is added", cxxopts::value<double>())
    ("rounds", "loop intensity --base lookup: add effects one after another, up to this many rounds", cxxopts::value<int>()->default_value("1"))
    ("min-gain", "loop intensity: smallest held-out MAE cut (share of before) for which an effect is added", cxxopts::value<double>()->default_value("0.05"))
    ("seed", "seed of the simulation", cxxopts::value<std::uint64_t>()->default_value("1"))
    ("held-out-seeds", "objects: simulation seeds per fold and model in the held-out table; loop objects: in its distribution check (fewer: faster, and a model with per-track errors pays Monte Carlo noise)", cxxopts::value<int>()->default_value(std::to_string(qualify::kHeldOutSeeds)))
    ("h,help", "this help");
  return opts;
}

// Options the commands share, checked once.
struct Common {
  std::uint64_t seed = 1;
  int held_out_seeds = qualify::kHeldOutSeeds;
  qualify::TermShrink shrink_terms = qualify::TermShrink::Off;
};

Common common_options(const cxxopts::ParseResult& a) {
  Common c;
  c.seed = a["seed"].as<std::uint64_t>();
  c.held_out_seeds = a["held-out-seeds"].as<int>();
  if (c.held_out_seeds < 1) throw Error("--held-out-seeds: expected >= 1, got " + std::to_string(c.held_out_seeds));
  const std::string shrink = a["term-shrink"].as<std::string>();
  if (shrink != "off" && shrink != "zero" && shrink != "pooled")
    throw Error("--term-shrink: expected off, zero or pooled, got \"" + shrink + "\"");
  c.shrink_terms = shrink == "zero"     ? qualify::TermShrink::TowardsZero
                   : shrink == "pooled" ? qualify::TermShrink::TowardsPooled
                                        : qualify::TermShrink::Off;
  return c;
}

int run_objects(const cxxopts::ParseResult& a, const Common& c) {
  const auto data = qualify::load_tracking(need(a, "kitti-tracking", "the KITTI tracking folder"),
                                           a["seqmap"].as<std::string>(), a["detector"].as<std::string>());
  const auto model = sensor::load_kpi_model(need(a, "model", "the KPI model JSON"));
  const fs::path out = need(a, "out", "the report folder");
  const auto j = qualify::qualify_objects(data, model, out, c.seed, a.count("nested") > 0, c.shrink_terms,
                                          a.count("pool-track-spread") > 0, c.held_out_seeds);
  std::cout << "overall similarity " << j["overall"]["similarity"].get<double>() << " (real-vs-real ceiling "
            << j["overall"]["ceiling"].get<double>() << ", ratio " << j["overall"]["ratio_to_ceiling"].get<double>()
            << ") over " << j["overall"]["kpis"].get<int>() << " KPIs\nwrote " << (out / "report.md") << "\n";
  return 0;
}

int run_intensity(const cxxopts::ParseResult& a) {
  const fs::path out = need(a, "out", "the report folder");
  const auto j = qualify::qualify_intensity(need(a, "model", "the intensity checkpoint"),
                                            need(a, "semantickitti", "the SemanticKITTI folder"), out);
  std::cout << "validation MAE " << j["overall"]["mae"].get<double>() << ", RMSE " << j["overall"]["rmse"].get<double>()
            << ", histogram intersection " << j["overall"]["similarity"]["intersection"].get<double>()
            << " (ceiling " << j["overall"]["similarity"]["ceiling"].get<double>() << ")\nwrote " << (out / "report.md")
            << "\n";
  return 0;
}

nlohmann::json run_loop_objects(const cxxopts::ParseResult& a, const Common& c, const fs::path& plots_dir) {
  qualify::LoopOptions lo;
  lo.plots_dir = plots_dir;
  if (a.count("threshold")) lo.threshold = a["threshold"].as<double>();
  if (a.count("out-model")) lo.out_model = a["out-model"].as<std::string>();
  lo.max_effects = a["max-effects"].as<int>();
  if (lo.max_effects < 0) throw Error("loop objects: --max-effects must be >= 0, got " + std::to_string(lo.max_effects));
  lo.seed = c.seed;
  lo.shrink_terms = c.shrink_terms;
  lo.pool_track_spread = a.count("pool-track-spread") > 0;
  lo.distribution_seeds = c.held_out_seeds;
  const auto data = qualify::load_tracking(need(a, "kitti-tracking", "the KITTI tracking folder"),
                                           a["seqmap"].as<std::string>(), a["detector"].as<std::string>(), 2);
  return qualify::loop_objects(data, lo);
}

nlohmann::json run_loop_intensity(const cxxopts::ParseResult& a, const fs::path& plots_dir) {
  qualify::IntensityLoopOptions io;
  if (a.count("threshold")) io.threshold = a["threshold"].as<double>();
  io.min_relative_gain = a["min-gain"].as<double>();
  io.rounds = a["rounds"].as<int>();
  io.plots_dir = plots_dir;
  io.base_model = qualify::parse_intensity_base(a["base"].as<std::string>());
  io.unet.steps = a["steps"].as<int>();
  io.unet.seeds = a["seeds"].as<int>();
  io.unet.threads = a["threads"].as<int>();
  io.unet.lookup_base = a.count("lookup-base") > 0;
  io.split = a["split"].as<std::string>();
  io.folds = a["folds"].as<int>();
  io.progress = !a.count("quiet");
  if (a.count("out-model")) io.out_model = a["out-model"].as<std::string>();
  return qualify::loop_intensity(need(a, "semantickitti", "the SemanticKITTI folder"), io);
}

// Every intensity candidate tried, with the loop's decision and its reason, so that a reader sees
// what was ruled out as well as what was added.
std::string intensity_candidates_markdown(const nlohmann::json& tested) {
  std::string md =
      "\nEvery candidate tested (held-out R^2 of the residual; significant = interval above 0):\n\n"
      "| feature | form | effect size | held-out R^2 | 95 % interval | significant | decision | reason |\n"
      "|---|---|---|---|---|---|---|---|\n";
  for (const auto& k : tested)
    md += "| " + k["feature"].get<std::string>() + " | " + k["form"].get<std::string>() + " | " +
          std::to_string(k["effect_size"].get<double>()) + " | " + std::to_string(k["held_out_r2"].get<double>()) +
          " | [" + std::to_string(k["interval95"][0].get<double>()) + ", " +
          std::to_string(k["interval95"][1].get<double>()) + "] | " + (k["significant"].get<bool>() ? "yes" : "no") +
          " | " + k.value("decision", "") + " | " + k.value("reason", "") + " |\n";
  return md;
}

// The loop's report for people, written beside the JSON (R.json -> R.md).
std::string loop_markdown(const std::string& sub, const nlohmann::json& j) {
  std::string md = "# Closed loop: " + sub + "\n\nMetric: " + j["metric"].get<std::string>() + "\n\n" +
                   (j.contains("split") ? "Split: " + j["split"].get<std::string>() + "; receptive-field half-width " +
                                              std::to_string(j["receptive_field_half_width"].get<int>()) + " columns\n\n"
                                        : std::string()) +
                   "Score: " + j["score_definition"].get<std::string>() + "; threshold " +
                   std::to_string(j["threshold"].get<double>()) +
                   "\n\n| feature | score | 95 % interval | explains |\n|---|---|---|---|\n";
  for (const auto& r : j["ranking"])
    md += "| " + r["feature"].get<std::string>() + " | " + std::to_string(r["score"].get<double>()) + " | " +
          (r.contains("interval95") ? "[" + std::to_string(r["interval95"][0].get<double>()) + ", " +
                                          std::to_string(r["interval95"][1].get<double>()) + "]"
                                    : std::string("-")) +
          " | " + (r.contains("target") ? r["target"].get<std::string>() : std::string("intensity")) + " |\n";
  if (j.contains("candidates_tested")) md += intensity_candidates_markdown(j["candidates_tested"]);
  md += "\nAlready used by the base model:";
  for (const auto& r : j["used_by_model"])
    md += " " + r["feature"].get<std::string>() +
          (r.contains("target") ? " on " + r["target"].get<std::string>() + " " + r["kind"].get<std::string>()
                                : std::string()) +
          " (" + std::to_string(r["score"].get<double>()) + ")";
  md += "\n\nAdded effect: **" + (j["added_effect"].is_null() ? std::string("none (no feature stands out)")
                                                               : j["added_effect"].get<std::string>()) +
        "**" + (j.contains("method") ? " via " + j["method"].get<std::string>() : std::string()) +
        "\n\n" + j["metric"].get<std::string>() + ": before " + std::to_string(j["before"].get<double>()) +
        ", after " + std::to_string(j["after"].get<double>()) + "\n";
  if (j.contains("after_simulated") && !j["after_simulated"].is_null())
    md += "\nWith the KPI manager's injected conditional mean (re-simulated): before " +
          std::to_string(j["before_simulated"].get<double>()) + ", after " +
          std::to_string(j["after_simulated"].get<double>()) + "\n";
  if (j.contains("added_effects") && !j["added_effects"].empty()) {
    md += "\n### Effects added (greedy: the best accepted bias form per target)\n\n| target | feature | kind | score | "
          "held-out before | after | re-simulated before | after | change [95%] | tracks better |\n"
          "|---|---|---|---|---|---|---|---|---|---|\n";
    auto num = [](const nlohmann::json& v) { return v.is_null() ? std::string("-") : qualify::fmt(v.get<double>(), 4); };
    for (const auto& e : j["added_effects"])
      md += "| " + e["target"].get<std::string>() + " | " + e["feature"].get<std::string>() + " | " +
            e["kind"].get<std::string>() + " | " + qualify::fmt(e["score"].get<double>()) + " | " + num(e["before"]) +
            " | " + num(e["after"]) + " | " + num(e["before_simulated"]) + " | " + num(e["after_simulated"]) + " | [" +
            qualify::fmt(e["change_interval95"][0].get<double>(), 4) + ", " +
            qualify::fmt(e["change_interval95"][1].get<double>(), 4) + "] | " +
            std::to_string(e["held_out_tracks_better"].get<int>()) + " of " +
            std::to_string(e["held_out_tracks"].get<int>()) + " |\n";
  }
  if (j.contains("rejected_effect"))
    md += "\nTried and rejected: " + j["rejected_effect"]["feature"].get<std::string>() + " (" +
          j["rejected_effect"]["why"].get<std::string>() + "; held-out error with it " +
          std::to_string(j["rejected_effect"]["held_out_after"].get<double>()) + ")\n";
  if (j.contains("seeds_before"))
    md += "\nBase model: " + j["base_model"].get<std::string>() + ". Per seed, before " + j["seeds_before"].dump() +
          ", after " + j["seeds_after"].dump() + " (class x range lookup: " +
          std::to_string(j["lookup_before"].get<double>()) + ")\n";
  if (j.contains("change_interval95"))
    md += "\nBlock-bootstrap 95% interval of the change: [" + std::to_string(j["change_interval95"][0].get<double>()) +
          ", " + std::to_string(j["change_interval95"][1].get<double>()) + "]\n";
  if (j.contains("held_out_tracks"))
    md += "\nHeld-out tracks better with it: " + std::to_string(j["held_out_tracks_better"].get<int>()) + " of " +
          std::to_string(j["held_out_tracks"].get<int>()) + "\n";
  if (j.contains("folds")) {
    md += "\n| fold | fit on | judged on | before | after |\n|---|---|---|---|---|\n";
    int k = 0;
    for (const auto& f : j["folds"]) {
      std::string fit, held;
      for (const auto& s : f["fit_sequences"]) fit += s.get<std::string>() + " ";
      for (const auto& s : f["held_out_sequences"]) held += s.get<std::string>() + " ";
      md += "| " + std::to_string(++k) + " | " + fit + "| " + held + "| " + std::to_string(f["before"].get<double>()) +
            " | " + std::to_string(f["after"].get<double>()) + " |\n";
    }
  }
  if (j.contains("plot"))
    md += "\n![residual vs " + j["ranking"][0]["feature"].get<std::string>() + "](" + j["plot"].get<std::string>() +
          ")\n\nGrey bars: mean held-out residual per bin of the feature; orange: the table fitted on the fit split.\n";
  if (j.contains("added_kind") && !j["added_kind"].is_null())
    md += "\nForm of the added effect: " + j["added_kind"].get<std::string>() + "; " +
          j["error_metric"].get<std::string>() + " before " + qualify::fmt(j["error_before"].get<double>(), 4) +
          ", after " + qualify::fmt(j["error_after"].get<double>(), 4) + "\n";
  if (j.contains("candidates")) md += qualify::candidates_markdown(j["candidates"]);
  if (j.contains("false_positives")) md += qualify::obj::fp_markdown(j["false_positives"]);
  return md;
}

int run_loop(const std::string& sub, const cxxopts::ParseResult& a, const Common& c) {
  const fs::path report = need(a, "report", "the JSON report to write");
  const fs::path plots_dir = report.parent_path().empty() ? fs::path(".") : report.parent_path();
  nlohmann::json j;
  if (sub == "objects") j = run_loop_objects(a, c, plots_dir);
  else if (sub == "intensity") j = run_loop_intensity(a, plots_dir);
  else throw Error("loop: unknown domain \"" + sub + "\" (expected objects or intensity)");
  write_file_atomically(report, j.dump(2) + "\n");
  fs::path md_path = report;
  md_path.replace_extension(".md");
  write_file_atomically(md_path, loop_markdown(sub, j));
  print_loop(j);
  std::cout << "wrote " << report << "\n";
  return 0;
}

int run(int argc, char** argv) {
  if (argc < 2 || std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h") {
    std::cout << kUsage;
    return argc < 2 ? 1 : 0;
  }
  const std::string cmd = argv[1];
  if (cmd == "range-noise") return qualify::run_range_noise(argc - 1, argv + 1);
  if (cmd == "returns") return qualify::run_returns(argc - 1, argv + 1);
  std::string sub;
  int shift = 1;
  if (cmd == "loop" && argc >= 3 && std::string(argv[2]) == "returns") return qualify::run_loop_returns(argc - 2, argv + 2);
  if (cmd == "loop" && argc >= 3 && std::string(argv[2]) == "range-noise") return qualify::run_loop_range_noise(argc - 2, argv + 2);
  if (cmd == "loop" && argc >= 3 && std::string(argv[2]) == "intensity-spread")
    return qualify::run_loop_intensity_spread(argc - 2, argv + 2);
  if (cmd == "loop") {
    if (argc < 3) throw Error("loop: expected `objects` or `intensity` after `loop`");
    sub = argv[2];
    shift = 2;
  }
  cxxopts::Options opts = command_options(cmd == "loop" ? "lidar-qualify loop " + sub : "lidar-qualify " + cmd);
  const auto a = opts.parse(argc - shift, argv + shift);
  if (a.count("help")) {
    std::cout << opts.help() << "\n";
    return 0;
  }
  if (!a.unmatched().empty()) throw Error("unexpected argument \"" + a.unmatched().front() + "\"");
  const Common c = common_options(a);
  if (cmd == "objects") return run_objects(a, c);
  if (cmd == "intensity") return run_intensity(a);
  if (cmd == "loop") return run_loop(sub, a, c);
  throw Error("unknown command \"" + cmd + "\" (expected objects, intensity, loop or range-noise)");
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 1;
  }
}
