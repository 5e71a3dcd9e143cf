// The command-line side shared by the spread loops (loop_rounds.h).
#include "qualify/range_noise/loop_rounds.h"

#include <algorithm>
#include <iostream>
#include <sstream>

#include "common/error.h"
#include "sensor/range_noise.h"

namespace lidarsim::qualify {

void add_loop_round_options(cxxopts::Options& opts) {
  opts.add_options()
    ("base-terms", "features the base already carries, comma-separated", cxxopts::value<std::string>()->default_value(""))
    ("rounds", "rerun with the added term in the base, up to this many times", cxxopts::value<int>()->default_value("1"))
    ("folds", "azimuth folds", cxxopts::value<int>()->default_value("4"))
    ("sectors", "azimuth sectors (a multiple of --folds)", cxxopts::value<int>()->default_value("64"))
    ("guard-deg", "guard band at each boundary between folds, deg", cxxopts::value<double>()->default_value("0.5"))
    ("min-gain", "smallest held-out cut added", cxxopts::value<double>()->default_value("0.002"));
}

RangeLoopOptions loop_options_from(const cxxopts::ParseResult& a) {
  RangeLoopOptions o;
  o.folds = a["folds"].as<int>(), o.sectors = a["sectors"].as<int>();
  o.guard_deg = a["guard-deg"].as<double>(), o.min_gain = a["min-gain"].as<double>();
  if (!(o.guard_deg >= 0) || o.guard_deg * 2 >= 360.0 / std::max(1, o.sectors))
    throw Error("--guard-deg: must be >= 0 and less than half a sector");
  std::stringstream ss(a["base-terms"].as<std::string>());
  const auto& known = sensor::range_noise_term_features();
  for (std::string t; std::getline(ss, t, ',');) {
    if (t.empty()) continue;
    if (t != "range growth" && std::find(known.begin(), known.end(), t) == known.end())
      throw Error("--base-terms: unknown feature \"" + t + "\" (laser, range, class, material, azimuth, incidence, intensity, range growth)");
    o.base_terms.push_back(t);
  }
  return o;
}

RangeLoopResult run_loop_rounds(const cxxopts::ParseResult& a, RangeLoopOptions& o,
                                const std::function<RangeLoopResult(const RangeLoopOptions&)>& run,
                                const std::function<nlohmann::json(const RangeLoopResult&)>& json_of,
                                const std::string& command, const std::string& subject, const std::string& unit,
                                nlohmann::json& report, std::string& md) {
  const int rounds = std::max(1, a["rounds"].as<int>());
  RangeLoopResult r;
  for (int k = 0; k < rounds; ++k) {
    r = run(o);
    nlohmann::json j = json_of(r);
    j["base_terms"] = o.base_terms;
    report["rounds"].push_back(j);
    std::string terms;
    for (const auto& t : o.base_terms) terms += (terms.empty() ? "" : ", ") + t;
    md += to_markdown(r, command, subject) + "\nBase terms (round " + std::to_string(k + 1) + "): " +
          (terms.empty() ? "none" : terms) + "\n\n";
    std::cout << "round " << k + 1 << ": " << r.scans << " scans, " << r.residuals << " " << unit << " (" << r.scored
              << " scored); held-out log-scale error " << r.error_before << " -> " << r.error_after << ", added: "
              << (r.added_feature.empty() ? "nothing" : r.added_feature) << "\n";
    for (const auto& c : r.candidates)
      std::cout << "  " << c.feature << " " << to_string(c.form) << ": cut " << c.score << " (bound " << c.selection_lower
                << ") " << c.decision << ": " << c.reason << "\n";
    if (r.added < 0) break;
    o.base_terms.push_back(base_term_name(r.candidates[r.added]));
  }
  return r;
}

}  // namespace lidarsim::qualify
