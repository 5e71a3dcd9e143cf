// The intensity half of the loop's campaign of random planted effects: real geometry
// (SemanticKITTI sequence 00, nuScenes-lidarseg, RELLIS-3D from ../shared/data), intensity from a
// hidden base model x one planted effect with random parameters (data/planted_scans.h), the loop
// (qualify::loop_intensity) run blind, and each draw scored:
//   detect families  recall = the planted feature is the added effect AND the held-out excess
//                    error after <= 0.7 x before;
//   class_gain       the base represents it: correct when nothing is added;
//   control          false add = anything added.
// Excess error = sqrt(max(0, rmse^2 - sigma^2)) from the loop's held-out RMSE and the known noise
// sigma: the error against the hidden noise-free truth. Each draw's control twin (same seed, no
// effect) is run too: its excess is the base's own floor, and "recall above floor" applies the same
// rule to sqrt(max(0, excess^2 - floor^2)) (data/planted_scans.h says why).
//   bench_loop_campaign_intensity [--draws 10] [--seed 1] [--families a,b] [--data semantickitti]
//                                 [--base lookup|unet] [--sigma 0.03] [--json out.json]
// Progress on stderr, the table on stdout, every draw in the JSON (written atomically).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cxxopts.hpp>
#include <filesystem>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "bench/campaign_scan_sources.h"
#include "common/atomic_file.h"
#include "common/error.h"
#include "data/planted_scans.h"
#include "qualify/intensity/intensity.h"

namespace fs = std::filesystem;
using namespace lidarsim;
using bench::Source;
using bench::load_sources;

namespace {

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const size_t m = v.size() / 2;
  return v.size() % 2 ? v[m] : 0.5 * (v[m - 1] + v[m]);
}

struct FamilyRows {
  int draws = 0, hits = 0, hits_above_floor = 0, false_adds = 0;
  std::vector<double> before, after, floor, seconds;
  std::map<std::string, int> named;  // added effect ("-" for none) -> draws
};

struct DrawSettings {
  double sigma = 0.03;
  bool binned_base = true;
  qualify::IntensityLoopOptions loop;
};

nlohmann::json run_draw(const Source& src, data::PlantedScanFamily family, std::uint64_t seed, const DrawSettings& settings,
                        FamilyRows& rows) {
  const auto t0 = std::chrono::steady_clock::now();
  const data::PlantedScanDraw draw = data::draw_planted(family, seed, src.geometry, settings.sigma, settings.binned_base);
  const nlohmann::json loop = qualify::loop_intensity(data::plant(src.geometry, draw), settings.loop);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  // The control twin (same seed: same hidden base and noise, no effect) gives the base's own floor.
  double floor = data::score_planted(draw, loop).excess_before;
  if (family != data::PlantedScanFamily::Control) {
    const auto twin = data::draw_planted(data::PlantedScanFamily::Control, seed, src.geometry, settings.sigma, settings.binned_base);
    floor = data::score_planted(twin, qualify::loop_intensity(data::plant(src.geometry, twin), settings.loop)).excess_before;
  }
  const data::PlantedScore s = data::score_planted(draw, loop, floor);
  ++rows.draws;
  rows.hits += s.hit;
  rows.hits_above_floor += s.hit_above_floor;
  rows.false_adds += family == data::PlantedScanFamily::Control ? !s.added.empty() : s.false_add;
  rows.before.push_back(s.excess_before);
  rows.after.push_back(s.excess_after);
  rows.floor.push_back(floor);
  rows.seconds.push_back(seconds);
  ++rows.named[s.added.empty() ? "-" : s.added];
  nlohmann::json top = nlohmann::json::array();
  for (size_t k = 0; k < std::min<size_t>(3, loop["ranking"].size()); ++k) top.push_back(loop["ranking"][k]);
  nlohmann::json j = draw.to_json();
  j["data"] = src.name;
  j["added_effect"] = loop["added_effect"];
  j["method"] = loop.value("method", "");
  j["before"] = loop["before"], j["after"] = loop["after"];
  j["rmse_before"] = loop["rmse_before"], j["rmse_after"] = loop["rmse_after"];
  j["excess_rmse_before"] = s.excess_before, j["excess_rmse_after"] = s.excess_after;
  j["floor"] = floor, j["excess_above_floor_before"] = s.above_floor_before, j["excess_above_floor_after"] = s.above_floor_after;
  j["named"] = s.named, j["cut"] = s.cut, j["hit"] = s.hit, j["hit_above_floor"] = s.hit_above_floor, j["false_add"] = s.false_add;
  j["ranking_top3"] = top;
  j["cross_fit"] = loop.value("cross_fit", "");
  j["scenery_correlation"] = {{"between_scans", loop.value("scenery_correlation_between_scans", 0.0)},
                              {"between_time_blocks", loop.value("scenery_correlation_between_time_blocks", 0.0)}};
  if (loop.contains("rejected_effect")) j["rejected_effect"] = loop["rejected_effect"];
  // Why a draw is missed: the planted feature's own candidates (score, decision, reason), the
  // refits of the top feature, and why the top feature was not tried.
  nlohmann::json planted = nlohmann::json::array();
  for (const auto& k : loop["candidates_tested"])
    if (std::find(draw.effect.accepted.begin(), draw.effect.accepted.end(), k["feature"].get<std::string>()) !=
        draw.effect.accepted.end())
      planted.push_back(k);
  j["planted_candidates"] = planted;
  j["refits"] = loop["candidates_held_out_mae"];
  if (loop.contains("top_not_tried")) j["top_not_tried"] = loop["top_not_tried"];
  if (loop.contains("azimuth_cross_fit")) j["azimuth_cross_fit"] = loop["azimuth_cross_fit"];
  j["seconds"] = seconds;
  std::fprintf(stderr, "  %-17s %-13s seed %-12llu added %-16s excess %.4f -> %.4f (floor %.4f) %s%s (%.1f s)\n",
               data::to_string(family).c_str(), src.name.c_str(), static_cast<unsigned long long>(seed),
               s.added.empty() ? "-" : s.added.c_str(), s.excess_before, s.excess_after, floor, s.hit ? "hit" : "MISS",
               s.hit_above_floor ? "" : " (miss above floor)", seconds);
  return j;
}

std::string named_list(const std::map<std::string, int>& named) {
  std::vector<std::pair<int, std::string>> v;
  for (const auto& [k, n] : named) v.push_back({-n, k});
  std::sort(v.begin(), v.end());
  std::string s;
  for (const auto& [n, k] : v) s += (s.empty() ? "" : ", ") + k + " " + std::to_string(-n);
  return s;
}

// The table per family on stdout (markdown) and the overall line; returns them as JSON.
nlohmann::json print_table(const std::vector<data::PlantedScanFamily>& families, const std::vector<FamilyRows>& rows,
                           const data::Dataset& geometry, double sigma) {
  std::printf("| family | scoring | planted feature | draws | recall | recall above floor | false adds | median excess before | median excess after | median floor | median s | added effects |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  nlohmann::json table = nlohmann::json::array();
  int detect_floor_hits = 0;
  int detect_draws = 0, detect_hits = 0, absorbed_draws = 0, absorbed_hits = 0, control_draws = 0, control_adds = 0;
  for (size_t f = 0; f < families.size(); ++f) {
    const auto& r = rows[f];
    const auto sample = data::draw_planted(families[f], 0, geometry, sigma).effect;
    const std::string scoring = data::to_string(sample.scoring);
    const double recall = r.draws ? static_cast<double>(r.hits) / r.draws : 0;
    const bool control = sample.scoring == data::PlantedScoring::Control;
    const std::string recall_s = control ? "-" : std::to_string(r.hits) + "/" + std::to_string(r.draws);
    const std::string floor_s = control ? "-" : std::to_string(r.hits_above_floor) + "/" + std::to_string(r.draws);
    std::printf("| %s | %s | %s | %d | %s | %s | %d | %.4f | %.4f | %.4f | %.1f | %s |\n", data::to_string(families[f]).c_str(),
                scoring.c_str(), sample.feature.empty() ? "-" : sample.feature.c_str(), r.draws, recall_s.c_str(),
                floor_s.c_str(), r.false_adds, median(r.before), median(r.after), median(r.floor), median(r.seconds),
                named_list(r.named).c_str());
    table.push_back({{"family", data::to_string(families[f])}, {"scoring", scoring}, {"feature", sample.feature},
                     {"draws", r.draws}, {"hits", r.hits}, {"recall", recall}, {"hits_above_floor", r.hits_above_floor},
                     {"false_adds", r.false_adds}, {"median_floor", median(r.floor)},
                     {"median_excess_before", median(r.before)}, {"median_excess_after", median(r.after)},
                     {"median_seconds", median(r.seconds)}, {"added_effects", r.named}});
    if (sample.scoring == data::PlantedScoring::Detect) detect_draws += r.draws, detect_hits += r.hits, detect_floor_hits += r.hits_above_floor;
    if (sample.scoring == data::PlantedScoring::Absorbed) absorbed_draws += r.draws, absorbed_hits += r.hits;
    if (sample.scoring == data::PlantedScoring::Control) control_draws += r.draws, control_adds += r.false_adds;
  }
  std::printf("\noverall: recall %d/%d (detect families; above the base's floor %d/%d), absorbed correct %d/%d, control false adds %d/%d\n",
              detect_hits, detect_draws, detect_floor_hits, detect_draws, absorbed_hits, absorbed_draws, control_adds, control_draws);
  const nlohmann::json overall = {{"detect_hits", detect_hits}, {"detect_draws", detect_draws}, {"detect_hits_above_floor", detect_floor_hits},
                                  {"absorbed_correct", absorbed_hits}, {"absorbed_draws", absorbed_draws},
                                  {"control_false_adds", control_adds}, {"control_draws", control_draws}};
  return {{"table", table}, {"overall", overall}};
}

}  // namespace

int main(int argc, char** argv) try {
  cxxopts::Options opts("bench_loop_campaign_intensity", "Random planted intensity effects on real geometry, the loop run blind, scored.");
  opts.add_options()("draws", "draws per family", cxxopts::value<int>()->default_value("10"))(
      "seed", "campaign seed", cxxopts::value<std::uint64_t>()->default_value("1"))(
      "families", "comma-separated families (default: all)", cxxopts::value<std::string>()->default_value(""))(
      "data", "semantickitti | nuscenes | rellis | mixed (draws cycle over the three)",
      cxxopts::value<std::string>()->default_value("semantickitti"))(
      "base", "the loop's base: lookup | unet (slow: ~minutes per draw)", cxxopts::value<std::string>()->default_value("lookup"))(
      "smooth-base", "hidden base with a smooth range fall-off (default: at the 5 m bin centres, which the lookup base represents exactly)")(
      "sigma", "noise sigma of the planted intensity (0-1 scale)", cxxopts::value<double>()->default_value("0.03"))(
      "shared", "measured data folder (default: ../shared/data beside the source tree)", cxxopts::value<std::string>())(
      "json", "write every draw and the table here (atomically)", cxxopts::value<std::string>())("h,help", "show this help");
  const auto args = opts.parse(argc, argv);
  if (args.count("help")) {
    std::printf("%s\n", opts.help().c_str());
    return 0;
  }
  const fs::path source_dir = LIDARSIM_SOURCE_DIR;
  const fs::path shared = args.count("shared") ? fs::path(args["shared"].as<std::string>()) : source_dir / "../shared/data";
  const int draws = std::max(1, args["draws"].as<int>());
  const std::uint64_t seed = args["seed"].as<std::uint64_t>();
  const double sigma = args["sigma"].as<double>();
  std::vector<data::PlantedScanFamily> families;
  {
    std::stringstream ss(args["families"].as<std::string>());
    for (std::string f; std::getline(ss, f, ',');)
      if (!f.empty()) families.push_back(data::planted_scan_family_from_string(f));
    if (families.empty()) families = data::all_planted_families();
  }
  DrawSettings settings;
  settings.sigma = sigma;
  settings.binned_base = !args.count("smooth-base");
  settings.loop.base_model = qualify::parse_intensity_base(args["base"].as<std::string>());
  const qualify::IntensityLoopOptions& loop_options = settings.loop;
  const std::vector<Source> sources = load_sources(args["data"].as<std::string>(), shared, source_dir);

  const auto t0 = std::chrono::steady_clock::now();
  nlohmann::json all = nlohmann::json::array();
  std::vector<FamilyRows> rows(families.size());
  for (size_t f = 0; f < families.size(); ++f) {
    std::fprintf(stderr, "%s: %d draws\n", data::to_string(families[f]).c_str(), draws);
    for (int d = 0; d < draws; ++d) {
      const std::uint64_t draw_seed = seed * 1000003ULL + static_cast<std::uint64_t>(families[f]) * 1000ULL + d;
      all.push_back(run_draw(sources[d % sources.size()], families[f], draw_seed, settings, rows[f]));
    }
  }
  const double total_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();

  std::printf("Intensity loop campaign: data %s, base %s, %d draws per family, seed %llu, noise sigma %.3f\n",
              args["data"].as<std::string>().c_str(), qualify::to_string(loop_options.base_model).c_str(), draws,
              static_cast<unsigned long long>(seed), sigma);
  std::printf("Hidden base: albedo per class x exp(-range / L), %s. Excess error = sqrt(max(0, held-out RMSE^2 - sigma^2)):\nthe error against the hidden noise-free truth.\n\n", settings.binned_base ? "range at the 5 m bin centres" : "smooth in range");
  nlohmann::json summary = print_table(families, rows, sources[0].geometry, sigma);
  summary["overall"]["seconds"] = total_s;
  std::printf("%.0f s for %zu draws (each with its control twin)\n", total_s, all.size());
  if (args.count("json")) {
    nlohmann::json out = {{"data", args["data"].as<std::string>()}, {"base", qualify::to_string(loop_options.base_model)}, {"seed", seed},
                          {"draws_per_family", draws}, {"sigma", sigma},
                          {"hidden_base_fall_off", settings.binned_base ? "5 m range-bin centre" : "smooth"},
                          {"excess_error", "sqrt(max(0, rmse^2 - sigma^2)) of the loop's held-out rmse_before / rmse_after"},
                          {"recall_rule", "added_effect in the accepted names and excess after <= 0.7 x before"},
                          {"floor", "excess_before of the draw's control twin (same seed: same hidden base and noise, no effect); "
                                    "above floor = sqrt(max(0, excess^2 - floor^2))"},
                          {"seconds", "median_seconds: the draw's own loop run (its control twin's run not counted)"},
                          {"overall", summary["overall"]}, {"table", summary["table"]}, {"draws", all}};
    write_file_atomically(args["json"].as<std::string>(), out.dump(1));
    std::fprintf(stderr, "wrote %s\n", args["json"].as<std::string>().c_str());
  }
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "error: %s\n", e.what());
  return 1;
}
