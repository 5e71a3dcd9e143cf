// The loop on the spread of intensity, on random planted spreads: real geometry (SemanticKITTI
// sequence 00, nuScenes-lidarseg, RELLIS-3D from ../shared/data), intensity from a hidden base
// (data/planted_scans.h: albedo per class x range fall-off) plus Gaussian noise whose spread one
// planted effect widens where it acts (qualify/intensity/intensity_spread_loop.h), the loop
// (qualify::loop_intensity_spread) run blind, and each draw scored against the truth:
//   recall     the planted feature is the added one AND the RMS error of the predicted log-scale
//              against the true one, on the loop's held-out returns, after <= 0.7 x before;
//   control    false add = anything added.
//   bench_loop_campaign_intensity_spread [--draws 10] [--seed 1] [--families a,b]
//                                        [--data semantickitti|nuscenes|rellis|mixed] [--json out.json]
// Progress on stderr, the table on stdout, every draw in the JSON (written atomically).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cxxopts.hpp>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "bench/campaign_scan_sources.h"
#include "common/atomic_file.h"
#include "data/planted_scans.h"
#include "qualify/intensity/intensity_spread_loop.h"

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

constexpr double kSpreadRecallRatio = 0.7;

struct SpreadFamilyRow {
  int draws = 0, named = 0, recalled = 0, false_adds = 0;
  std::vector<double> before, after, seconds;
};

double median_of(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const size_t m = v.size() / 2;
  return v.size() % 2 ? v[m] : 0.5 * (v[m - 1] + v[m]);
}

nlohmann::json run_spread_draw(const bench::Source& src, qualify::PlantedSpreadFamily family, std::uint64_t seed,
                               double sigma, SpreadFamilyRow& row) {
  const auto t0 = std::chrono::steady_clock::now();
  const data::PlantedScanDraw base = data::draw_planted(data::PlantedScanFamily::Control, seed, src.geometry, sigma);
  const qualify::PlantedSpread e = qualify::draw_planted_spread(family, seed, src.geometry, sigma);
  const data::Dataset ds = qualify::plant_spread(src.geometry, base, e, seed);
  const qualify::IntensitySpreadOptions o;
  const auto residuals = qualify::intensity_spread_residuals(ds, o);
  const qualify::RangeLoopResult r = qualify::loop_intensity_spread(ds, o);
  const qualify::SpreadTruth t = qualify::spread_truth(residuals, r, e, sigma);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const bool control = family == qualify::PlantedSpreadFamily::Control;
  const bool named = !control && std::find(e.accepted.begin(), e.accepted.end(), r.added_feature) != e.accepted.end();
  const bool recalled = named && t.after <= kSpreadRecallRatio * t.before;
  const bool false_add = !r.added_feature.empty() && !named;
  ++row.draws, row.named += named, row.recalled += recalled, row.false_adds += false_add;
  row.before.push_back(t.before), row.after.push_back(t.after), row.seconds.push_back(seconds);
  std::fprintf(stderr, "  %s %s seed %llu: added %s, truth %.3f -> %.3f%s (%.1f s)\n", src.name.c_str(),
               qualify::to_string(family).c_str(), static_cast<unsigned long long>(seed),
               r.added_feature.empty() ? "nothing" : r.added_feature.c_str(), t.before, t.after,
               control ? (false_add ? " FALSE ADD" : "") : (recalled ? " recalled" : " missed"), seconds);
  nlohmann::json ranked = nlohmann::json::array();  // the best few, to read a miss by
  for (std::size_t k = 0; k < r.candidates.size() && k < 6; ++k)
    ranked.push_back({{"feature", r.candidates[k].feature}, {"form", to_string(r.candidates[k].form)},
                      {"score", r.candidates[k].score}, {"selection_lower", r.candidates[k].selection_lower}});
  return {{"data", src.name}, {"family", qualify::to_string(family)}, {"seed", seed}, {"effect", e.parameters},
          {"accepted", e.accepted}, {"added", r.added_feature}, {"ranked", ranked}, {"named", named}, {"recalled", recalled},
          {"false_add", false_add}, {"truth_before", t.before}, {"truth_after", t.after}, {"scored", t.n},
          {"log_scale_error_before", r.error_before}, {"log_scale_error_after", r.error_after}, {"seconds", seconds}};
}

}  // namespace

int main(int argc, char** argv) try {
  cxxopts::Options opts("bench_loop_campaign_intensity_spread",
                        "Random planted intensity spreads on real geometry, the spread loop run blind, scored against the truth.");
  opts.add_options()("draws", "draws per family", cxxopts::value<int>()->default_value("10"))(
      "seed", "campaign seed", cxxopts::value<std::uint64_t>()->default_value("1"))(
      "families", "comma-separated families (default: all)", cxxopts::value<std::string>()->default_value(""))(
      "data", "semantickitti | nuscenes | rellis | mixed (draws cycle over the three)",
      cxxopts::value<std::string>()->default_value("semantickitti"))(
      "sigma", "the hidden base's noise sigma (0-1 scale) that the plants widen", cxxopts::value<double>()->default_value("0.03"))(
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
  std::vector<qualify::PlantedSpreadFamily> families;
  {
    std::stringstream ss(args["families"].as<std::string>());
    for (std::string f; std::getline(ss, f, ',');)
      if (!f.empty()) families.push_back(qualify::planted_spread_family_from_string(f));
    if (families.empty()) families = qualify::all_planted_spread_families();
  }
  const std::vector<bench::Source> sources = bench::load_sources(args["data"].as<std::string>(), shared, source_dir);
  const auto t0 = std::chrono::steady_clock::now();
  nlohmann::json all = nlohmann::json::array(), table = nlohmann::json::array();
  std::vector<SpreadFamilyRow> rows(families.size());
  for (size_t f = 0; f < families.size(); ++f) {
    std::fprintf(stderr, "%s: %d draws\n", qualify::to_string(families[f]).c_str(), draws);
    for (int d = 0; d < draws; ++d) {
      const std::uint64_t draw_seed = seed * 1000003ULL + static_cast<std::uint64_t>(families[f]) * 1000ULL + d;
      all.push_back(run_spread_draw(sources[d % sources.size()], families[f], draw_seed, sigma, rows[f]));
    }
  }
  const double total_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf("Intensity-spread loop campaign: data %s, %d draws per family, seed %llu, base noise sigma %.3f\n",
              args["data"].as<std::string>().c_str(), draws, static_cast<unsigned long long>(seed), sigma);
  std::printf("Truth error: RMS of (predicted - true log-scale) on the loop's held-out returns; recall: named and after <= 0.7 x before.\n\n");
  std::printf("%-16s %6s %6s %9s %10s %14s %14s %8s\n", "family", "draws", "named", "recalled", "false_adds", "median_before",
              "median_after", "med_s");
  int effect_draws = 0, effect_recalled = 0, control_draws = 0, control_false = 0;
  for (size_t f = 0; f < families.size(); ++f) {
    const auto& r = rows[f];
    const bool control = families[f] == qualify::PlantedSpreadFamily::Control;
    (control ? control_draws : effect_draws) += r.draws;
    (control ? control_false : effect_recalled) += control ? r.false_adds : r.recalled;
    std::printf("%-16s %6d %6d %9d %10d %14.4f %14.4f %8.1f\n", qualify::to_string(families[f]).c_str(), r.draws, r.named,
                r.recalled, r.false_adds, median_of(r.before), median_of(r.after), median_of(r.seconds));
    table.push_back({{"family", qualify::to_string(families[f])}, {"draws", r.draws}, {"named", r.named},
                     {"recalled", r.recalled}, {"false_adds", r.false_adds}, {"median_truth_before", median_of(r.before)},
                     {"median_truth_after", median_of(r.after)}, {"median_seconds", median_of(r.seconds)}});
  }
  std::printf("overall: recall %d/%d over effect families; false adds on controls %d/%d; %.0f s\n", effect_recalled,
              effect_draws, control_false, control_draws, total_s);
  if (args.count("json")) {
    const nlohmann::json out = {{"data", args["data"].as<std::string>()}, {"seed", seed}, {"draws_per_family", draws},
                                {"sigma", sigma}, {"seconds", total_s},
                                {"overall", {{"recalled", effect_recalled}, {"effect_draws", effect_draws},
                                             {"false_adds", control_false}, {"control_draws", control_draws}}},
                                {"table", table}, {"draws", all}};
    write_file_atomically(args["json"].as<std::string>(), out.dump(1));
    std::fprintf(stderr, "wrote %s\n", args["json"].as<std::string>().c_str());
  }
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "error: %s\n", e.what());
  return 1;
}
