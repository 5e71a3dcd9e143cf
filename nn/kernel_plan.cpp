#include "nn/kernel_plan.h"

#include <chrono>
#include <cstdio>
#include <nlohmann/json.hpp>

#include "common/error.h"
#include "nn/conv3x3.h"
#include "nn/conv3x3_amx.h"
#include "nn/conv3x3_bf16.h"
#include "nn/kernel_cache.h"
#include "nn/kernel_calibration.h"
#include "nn/winograd.h"

namespace lidarsim::nn {

namespace {
constexpr const char* kPassNames[] = {"forward", "input_grad", "weight_grad", "bf16_forward"};
constexpr const char* kAlgoNames[] = {"direct", "winograd", "fp32", "avx512_bf16", "amx"};

template <typename E, std::size_t N>
E parse_name(const std::string& text, const char* const (&names)[N], const std::string& field) {
  for (std::size_t i = 0; i < N; ++i)
    if (text == names[i]) return static_cast<E>(i);
  std::string all;
  for (std::size_t i = 0; i < N; ++i) all += (i ? ", " : "") + std::string(names[i]);
  throw Error(field + ": expected one of " + all + ", got \"" + text + "\"");
}

bool is_bf16_algo(ConvAlgo a) { return a == ConvAlgo::fp32 || a == ConvAlgo::avx512_bf16 || a == ConvAlgo::amx; }

// Whether `algo` can run `key` on this build and CPU at key.isa (a checkpoint's plan from
// another level never reaches here: its keys carry their level).
bool algo_runs(const ConvKey& key, ConvAlgo algo) {
  if ((key.pass == ConvPass::bf16_forward) != is_bf16_algo(algo)) return false;
  switch (algo) {
    case ConvAlgo::winograd: return detail::winograd_available();
    case ConvAlgo::avx512_bf16: return key.isa >= Isa::avx512_bf16;
    case ConvAlgo::amx: return key.isa >= Isa::amx_bf16;
    default: return true;
  }
}
}  // namespace

const char* to_string(ConvPass p) { return kPassNames[static_cast<int>(p)]; }
const char* to_string(ConvAlgo a) { return kAlgoNames[static_cast<int>(a)]; }
const char* to_string(PlanMode m) { return m == PlanMode::rule ? "rule" : "calibrated"; }

PlanMode parse_plan_mode(const std::string& text, const std::string& field) {
  if (text == "rule") return PlanMode::rule;
  if (text == "calibrated") return PlanMode::calibrated;
  throw Error(field + ": expected rule or calibrated, got \"" + text + "\"");
}

ConvAlgo rule_choice(const ConvKey& k, detail::Conv3x3Path path) {
  const bool wide = k.isa >= Isa::avx512;
  const auto fp32 = [&](int ci, int co) {
    const bool wino = wide ? detail::conv3x3_takes_winograd(ci, co, path)
                           : detail::conv3x3_avx2_takes_winograd(ci, co, k.n, k.h, k.w, path);
    return wino ? ConvAlgo::winograd : ConvAlgo::direct;
  };
  switch (k.pass) {
    case ConvPass::forward:
    case ConvPass::weight_grad: return fp32(k.ci, k.co);
    case ConvPass::input_grad: return fp32(k.co, k.ci);  // the input gradient is the conv co -> ci
    case ConvPass::bf16_forward:
      if (!detail::conv3x3_takes_bf16(k.n, k.ci, k.co, k.h, k.w, path)) return ConvAlgo::fp32;
      return detail::conv3x3_takes_amx(k.n, k.ci, k.co, k.h, k.w) ? ConvAlgo::amx : ConvAlgo::avx512_bf16;
  }
  return ConvAlgo::direct;
}

std::vector<ConvAlgo> candidates(const ConvKey& key) {
  const ConvAlgo rule = rule_choice(key);
  std::vector<ConvAlgo> out{rule};
  const bool bf16 = key.pass == ConvPass::bf16_forward;
  for (const ConvAlgo a : bf16 ? std::vector{ConvAlgo::fp32, ConvAlgo::avx512_bf16, ConvAlgo::amx}
                               : std::vector{ConvAlgo::direct, ConvAlgo::winograd})
    if (a != rule && algo_runs(key, a)) out.push_back(a);
  return out;
}

ConvAlgo KernelPlan::lookup(const ConvKey& key) {
  if (const auto it = entries_.find(key); it != entries_.end()) return it->second.algo;
  PlanEntry entry{rule_choice(key), {}};
  if (mode_ == PlanMode::calibrated) {
    auto disk = disk_.find(key.isa);
    if (disk == disk_.end()) disk = disk_.emplace(key.isa, read_kernel_cache(key.isa)).first;
    const auto hit = disk->second.find(key);
    if (hit != disk->second.end() && algo_runs(key, hit->second.algo)) {
      entry = hit->second;
    } else {
      if (!announced_)
        std::fprintf(stderr, "lidarsim: measuring the 3x3 conv kernels for each new layer shape on this CPU (%s, %s); kept in %s\n",
                     cpu_name().c_str(), nn::to_string(key.isa), kernel_cache_path(key.isa).c_str());
      announced_ = true;
      // The bf16 pass's fp32 candidate is what the fp32 forward would run: the plan's own choice.
      const ConvAlgo fwd = key.pass == ConvPass::bf16_forward
                               ? lookup(ConvKey{ConvPass::forward, key.n, key.ci, key.co, key.h, key.w, key.isa})
                               : ConvAlgo::direct;
      const auto t0 = std::chrono::steady_clock::now();
      entry = calibrate(key, fwd);
      calibration_seconds_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      disk->second[key] = entry;
      write_kernel_cache(key.isa, disk->second);
    }
  }
  entries_[key] = entry;
  return entry.algo;
}

void KernelPlan::set(const ConvKey& key, ConvAlgo algo) {
  if (!algo_runs(key, algo))
    throw Error(std::string("kernel plan: ") + to_string(key.pass) + " cannot take " + to_string(algo) + " here");
  entries_[key] = PlanEntry{algo, {}};
}

std::string KernelPlan::to_json() const {
  nlohmann::json choices = nlohmann::json::array();
  for (const auto& [k, e] : entries_)
    choices.push_back({{"pass", to_string(k.pass)}, {"n", k.n}, {"ci", k.ci}, {"co", k.co}, {"h", k.h}, {"w", k.w},
                       {"isa", nn::to_string(k.isa)}, {"algo", to_string(e.algo)}, {"seconds", e.seconds}});
  return nlohmann::json{{"mode", to_string(mode_)}, {"choices", choices}}.dump();
}

KernelPlan KernelPlan::from_json(const std::string& json, const std::string& where) {
  std::string field = "mode";
  try {
    const nlohmann::json j = nlohmann::json::parse(json);
    KernelPlan plan(parse_plan_mode(j.at("mode").get<std::string>(), where + ": mode"));
    const nlohmann::json& list = j.at(field = "choices");
    for (std::size_t i = 0; i < list.size(); ++i) {
      const nlohmann::json& c = list.at(i);
      field = "choices[" + std::to_string(i) + "]";
      ConvKey k;
      k.pass = parse_name<ConvPass>(c.at("pass").get<std::string>(), kPassNames, where + ": " + field + ".pass");
      k.n = c.at("n").get<int>(), k.ci = c.at("ci").get<int>(), k.co = c.at("co").get<int>();
      k.h = c.at("h").get<int>(), k.w = c.at("w").get<int>();
      k.isa = parse_isa(c.at("isa").get<std::string>(), where + ": " + field + ".isa");
      PlanEntry e;
      e.algo = parse_name<ConvAlgo>(c.at("algo").get<std::string>(), kAlgoNames, where + ": " + field + ".algo");
      if (c.contains("seconds")) e.seconds = c.at("seconds").get<std::map<std::string, double>>();
      if ((k.pass == ConvPass::bf16_forward) != is_bf16_algo(e.algo) || k.n < 1 || k.ci < 1 || k.co < 1 || k.h < 1 ||
          k.w < 1)
        throw Error(where + ": " + field + ": " + to_string(k.pass) + " cannot take " + to_string(e.algo) +
                    " (or a size is not positive)");
      plan.entries_[k] = e;
    }
    return plan;
  } catch (const nlohmann::json::exception& e) {
    throw Error(where + ": " + field + ": " + e.what());
  }
}

std::string KernelPlan::describe() const {
  std::string out;
  char line[256];
  for (const auto& [k, e] : entries_) {
    std::snprintf(line, sizeof line, "%s n%d %d->%d %dx%d %s: %s", to_string(k.pass), k.n, k.ci, k.co, k.h, k.w,
                  nn::to_string(k.isa), to_string(e.algo));
    out += line;
    if (!e.seconds.empty()) {
      out += " (";
      bool first = true;
      for (const auto& [name, s] : e.seconds) {
        std::snprintf(line, sizeof line, "%s%s %.3f ms", first ? "" : ", ", name.c_str(), s * 1e3);
        out += line;
        first = false;
      }
      out += ")";
    }
    out += "\n";
  }
  return out;
}

namespace detail {
ConvAlgo conv_choice(const ConvSettings& cs, ConvPass pass, int n, int ci, int co, int h, int w) {
  const ConvKey key{pass, n, ci, co, h, w, active_isa()};
  if (!cs.plan || cs.conv3x3 != Conv3x3Path::automatic) return rule_choice(key, cs.conv3x3);
  return cs.plan->lookup(key);
}
}  // namespace detail

}  // namespace lidarsim::nn
