// The range-noise half of the loop's campaign of random planted effects (issues 26, 27 item 7):
// the labelled SemanticKITTI sequence 00 scans from ../shared/data, one extra range noise planted
// along the beams with random parameters on top of the scans' own (qualify/range_noise/range_noise_loop.h:
// a spread growing with range, extra noise on 2-10 lasers, extra noise on one class; controls), the
// loop (qualify::loop_range_noise) run blind on the planted scans' residuals, scored:
//   detect families  recall = the planted feature is the added term AND the held-out excess over
//                    the oracle after <= 0.7 x before;
//   control          false add = anything added.
// The base is fitted on the same scans before the plant, with the terms the loop adds on them
// (printed: the model that was right before the sensor changed); each draw rotates the azimuth
// sector grid of the folds at random.
//   bench_loop_campaign_range_noise [--draws 10] [--seed 1] [--families a,b] [--max-scans 0] [--json out.json]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cxxopts.hpp>
#include <filesystem>
#include <map>
#include <sstream>

#include "common/atomic_file.h"
#include "common/error.h"
#include "qualify/range_noise/range_noise_cli.h"
#include "qualify/range_noise/range_noise_loop.h"

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

struct Rows {
  int draws = 0, hits = 0, false_adds = 0;
  std::vector<double> before, after, seconds;
  std::map<std::string, int> named;
};

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

nlohmann::json record(const qualify::RangeDrawResult& d, std::uint64_t seed, double seconds, Rows& rows) {
  const auto& r = d.loop;
  ++rows.draws;
  rows.hits += d.hit;
  rows.false_adds += d.false_add;
  rows.before.push_back(d.excess_before), rows.after.push_back(d.excess_after), rows.seconds.push_back(seconds);
  ++rows.named[r.added_feature.empty() ? "-" : r.added_feature];
  std::fprintf(stderr, "  %-13s seed %-10llu added %-10s excess %.5f -> %.5f %s (%.1f s)\n", qualify::to_string(d.effect.family).c_str(),
               static_cast<unsigned long long>(seed), r.added_feature.empty() ? "-" : r.added_feature.c_str(), d.excess_before,
               d.excess_after, d.hit ? "hit" : "MISS", seconds);
  nlohmann::json j = d.effect.parameters;
  j["added_effect"] = r.added_feature;
  j["error_before"] = r.error_before, j["error_after"] = r.error_after, j["error_oracle"] = d.error_oracle;
  j["excess_before"] = d.excess_before, j["excess_after"] = d.excess_after;
  j["named"] = d.named, j["cut"] = d.cut, j["hit"] = d.hit, j["false_add"] = d.false_add;
  nlohmann::json top = nlohmann::json::array();
  for (std::size_t k = 0; k < std::min<std::size_t>(3, r.candidates.size()); ++k)
    top.push_back({{"feature", r.candidates[k].feature}, {"form", to_string(r.candidates[k].form)}, {"score", r.candidates[k].score},
                   {"selection_lower", r.candidates[k].selection_lower}});
  j["ranking_top3"] = top;
  j["seconds"] = seconds;
  return j;
}

}  // namespace

int main(int argc, char** argv) try {
  cxxopts::Options opts("bench_loop_campaign_range_noise",
                        "Random planted range noise on measured HDL-64E scans, the loop run blind, scored.");
  opts.add_options()("draws", "draws per family", cxxopts::value<int>()->default_value("10"))(
      "seed", "campaign seed", cxxopts::value<std::uint64_t>()->default_value("1"))(
      "families", "comma-separated families (default: all)", cxxopts::value<std::string>()->default_value(""))(
      "shared", "measured data folder (default: ../shared/data beside the source tree)", cxxopts::value<std::string>())(
      "max-scans", "labelled scans used (0: all)", cxxopts::value<int>()->default_value("0"))(
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
  std::vector<qualify::PlantedRangeFamily> families;
  {
    std::stringstream ss(args["families"].as<std::string>());
    for (std::string f; std::getline(ss, f, ',');)
      if (!f.empty()) families.push_back(qualify::planted_range_family_from_string(f));
    if (families.empty()) families = qualify::all_planted_range_families();
  }
  const auto t_load = std::chrono::steady_clock::now();
  const fs::path dir = shared / "semantickitti-seq00-sample";
  std::vector<std::vector<pgm::Point>> scans;
  for (auto& s : qualify::read_labelled_scans("semantickitti", dir.string(), "", args["max-scans"].as<int>()))
    scans.push_back(std::move(s.points));
  const qualify::RangeLoopOptions options;
  const auto data = qualify::prepare_range_campaign(std::move(scans), pgm::BeamLayout::hdl64e(), options);
  const double load_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_load).count();
  std::string base_terms;
  for (const auto& t : data.base_terms) base_terms += (base_terms.empty() ? "" : ", ") + t;
  std::fprintf(stderr, "seq00: %zu scans, %zu residuals; base terms before the plant: %s (%.1f s)\n", data.scans.size(),
               data.reference.size(), base_terms.empty() ? "none" : base_terms.c_str(), load_s);

  const auto t0 = std::chrono::steady_clock::now();
  nlohmann::json all = nlohmann::json::array();
  std::vector<Rows> rows(families.size());
  for (std::size_t f = 0; f < families.size(); ++f) {
    std::fprintf(stderr, "%s: %d draws\n", qualify::to_string(families[f]).c_str(), draws);
    for (int d = 0; d < draws; ++d) {
      const std::uint64_t s = seed * 1000003ULL + static_cast<std::uint64_t>(families[f]) * 1000ULL + d;
      const auto t1 = std::chrono::steady_clock::now();
      const auto res = qualify::run_range_draw(data, families[f], s, options);
      all.push_back(record(res, s, std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count(), rows[f]));
    }
  }
  const double total_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf("Range-noise loop campaign: %d draws per family, seed %llu (SemanticKITTI seq00, %zu scans; base terms "
              "before the plant: %s; preparing %.0f s)\n\n",
              draws, static_cast<unsigned long long>(seed), data.scans.size(), base_terms.empty() ? "none" : base_terms.c_str(), load_s);
  std::printf("| family | draws | recall | false adds | median excess before | median excess after | median s | added |\n"
              "|---|---|---|---|---|---|---|---|\n");
  nlohmann::json table = nlohmann::json::array();
  int dd = 0, dh = 0, cd = 0, ca = 0, pf = 0;
  for (std::size_t f = 0; f < families.size(); ++f) {
    const auto& r = rows[f];
    const bool control = families[f] == qualify::PlantedRangeFamily::Control;
    std::string named;
    for (const auto& [k, n] : r.named) named += (named.empty() ? "" : ", ") + k + " " + std::to_string(n);
    const std::string recall = control ? "-" : std::to_string(r.hits) + "/" + std::to_string(r.draws);
    std::printf("| %s | %d | %s | %d | %.4f | %.4f | %.1f | %s |\n", qualify::to_string(families[f]).c_str(), r.draws,
                recall.c_str(), r.false_adds, median(r.before), median(r.after), median(r.seconds), named.c_str());
    table.push_back({{"family", qualify::to_string(families[f])}, {"draws", r.draws}, {"hits", r.hits},
                     {"false_adds", r.false_adds}, {"median_excess_before", median(r.before)},
                     {"median_excess_after", median(r.after)}, {"median_seconds", median(r.seconds)}, {"added_effects", r.named}});
    if (control) cd += r.draws, ca += r.false_adds;
    else dd += r.draws, dh += r.hits, pf += r.false_adds;
  }
  std::printf("\noverall: recall %d/%d (detect families; %d added another feature), control false adds %d/%d; %.0f s for %zu draws\n",
              dh, dd, pf, ca, cd, total_s, all.size());
  if (args.count("json")) {
    const nlohmann::json out = {{"seed", seed}, {"draws_per_family", draws}, {"base_terms_before_plant", data.base_terms},
                                {"overall", {{"detect_hits", dh}, {"detect_draws", dd}, {"control_false_adds", ca},
                                             {"control_draws", cd}, {"seconds", total_s}, {"prepare_seconds", load_s}}},
                                {"recall_rule", "added_effect in the accepted names and excess after <= 0.7 x before"},
                                {"excess", "held-out log-scale error minus the oracle's (held-out base widened by the planted spread)"},
                                {"table", table}, {"draws", all}};
    write_file_atomically(args["json"].as<std::string>(), out.dump(1));
    std::fprintf(stderr, "wrote %s\n", args["json"].as<std::string>().c_str());
  }
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "error: %s\n", e.what());
  return 1;
}
