#pragma once
// The command-line side shared by the loops built on range_noise_loop.h (`loop range-noise`,
// `loop intensity-spread`): the spread and the window options, the base terms, and the rounds.
#include <functional>
#include <string>
#include <vector>

#include <cxxopts.hpp>
#include <nlohmann/json.hpp>

#include "qualify/range_noise/range_noise_loop.h"

namespace lidarsim::qualify {

// --base-terms, --rounds, --folds, --sectors, --guard-deg, --min-gain on `opts`.
void add_loop_round_options(cxxopts::Options& opts);
// The loop's options from those (errors name the option: a guard of half a sector or more, an
// unknown base term).
RangeLoopOptions loop_options_from(const cxxopts::ParseResult& a);

// Up to a["rounds"] rounds: run(o) each round, its candidates printed (`unit` names a residual:
// "residuals", "returns"), its JSON (json_of, with "base_terms") appended to report["rounds"] and
// its Markdown (titled `subject`) to md; the added term joins o.base_terms for the next round.
// Stops when nothing is added. Returns the last round's result.
RangeLoopResult run_loop_rounds(const cxxopts::ParseResult& a, RangeLoopOptions& o,
                                const std::function<RangeLoopResult(const RangeLoopOptions&)>& run,
                                const std::function<nlohmann::json(const RangeLoopResult&)>& json_of,
                                const std::string& command, const std::string& subject, const std::string& unit,
                                nlohmann::json& report, std::string& md);

}  // namespace lidarsim::qualify
